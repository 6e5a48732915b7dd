"""The contract of every policy under SnapFlow, in the spirit of diffusers' ``SchedulerCommonTest``.

:class:`FlowPolicyContract` holds the checks; a subclass only says how to build, sample, save and load its policy.
Every LeRobot adapter runs them through :class:`tests.adapters.lerobot_contract.LeRobotAdapterContract`, which adds
what only LeRobot has (its own sampler, training forward and action API; the classes in ``test_contract_lerobot.py``
and ``test_contract_groot.py``), and every built-in policy (MiniVLA, MLP) through ``test_contract.py``'s
``BuiltinPolicyContract``. A new adapter or built-in policy without a class fails
``test_every_lerobot_adapter_runs_the_contract`` / ``test_every_built_in_policy_runs_the_contract``.

What every policy must show:
* wrapping changes no output bit at initialisation (phi_s's last layer starts at zero), even for the jump;
* the objective builds its targets without gradient, from the marginal velocity (s = t), and takes exactly one
  gradient pass per call, over every row; the prefix is encoded once;
* a generator reproduces the loss and its gradients bit for bit;
* the velocity has the shape of the noisy actions, and a context selects batch rows as the objective needs;
* with the trainer's freezing, gradients reach exactly ``expert_parameters()``, phi_s included;
* a save / load round trip keeps every tensor and every sample.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch
from torch import Tensor, nn

from snapflow import SNAPFLOW_1, FlowPolicy, SamplingMode, SnapFlowObjective, sample_actions
from snapflow.policies.checkpoint import CheckpointError
from snapflow.protocol import index_batch
from tests.lerobot_tiny import randomise_target_time

TEACHER_10 = SamplingMode(10, jump=False)


@dataclass
class VelocityCall:
    rows: int
    t: Tensor
    s: Tensor
    grad_enabled: bool
    output_requires_grad: bool


def record_calls(policy: nn.Module) -> dict[str, list]:
    """Count what the objective asks of ``policy``: every ``encode`` and every ``velocity`` call, as seen from outside
    (the instance's methods are wrapped, as :func:`snapflow.inference.compile_policy` replaces ``velocity``)."""
    calls: dict[str, list] = {"encode": [], "velocity": []}
    encode, velocity = policy.encode, policy.velocity

    def recording_encode(observation: Any) -> Any:
        calls["encode"].append(torch.is_grad_enabled())
        return encode(observation)

    def recording_velocity(x_t: Tensor, t: Tensor, s: Tensor, context: Any) -> Tensor:
        output = velocity(x_t, t, s, context)
        calls["velocity"].append(
            VelocityCall(
                x_t.shape[0], t.detach().clone(), s.detach().clone(), torch.is_grad_enabled(), output.requires_grad
            )
        )
        return output

    policy.encode, policy.velocity = recording_encode, recording_velocity
    return calls


class FlowPolicyContract:
    """The checks; subclasses implement the hooks below (not collected itself: its name does not start with Test)."""

    batch_size: ClassVar[int] = 4
    #: the graphs torch.compile makes of the one-step chunk under ``deploy``: one, the prefix and the jump together
    #: (None: the policy's own upstream code breaks the graph)
    deploy_graphs: ClassVar[int | None] = 1
    #: the torch.compile backend the compiled-fast-path test uses: inductor's C++ code generation is the same for every
    #: policy and costs up to 165 s a type on CI's cores, so types that only need their graph capture checked use
    #: ``aot_eager`` (dynamo's capture and AOTAutograd, no code generation); the deploy test still runs inductor
    compile_backend: ClassVar[str] = "inductor"

    # ---- what a subclass provides ----------------------------------------------------------------------------
    def build(self) -> nn.Module:
        """A fresh SnapFlow-wrapped policy (phi_s attached, as initialised); every call builds the same weights."""
        raise NotImplementedError

    def reference_sample(self, observation: Any, noise: Tensor, steps: int) -> Tensor:
        """``steps`` Euler steps of the same policy before wrapping, by its own sampler."""
        raise NotImplementedError

    def make_batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        """(observation, actions) of ``batch_size`` rows, as the objective receives them."""
        raise NotImplementedError

    def save(self, policy: nn.Module, directory: Path) -> None:
        raise NotImplementedError

    def load(self, directory: Path) -> nn.Module:
        raise NotImplementedError

    def loading(self) -> contextlib.AbstractContextManager:
        """What loading needs around it (pi0 / pi0.5 rebuild at tiny size only inside their context)."""
        return contextlib.nullcontext()

    # ---- fixtures ---------------------------------------------------------------------------------------------
    @pytest.fixture
    def policy(self) -> nn.Module:
        return self.build()

    @pytest.fixture
    def batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        return self.make_batch(policy)

    @pytest.fixture
    def fresh_compiler(self) -> None:
        """torch.compile's cache as a new process has it. Its entries are kept per code object, and every LeRobot
        adapter shares its base's ``velocity``: entries from earlier tests on this worker would be checked on each
        call (torch 2.10 computes a recompilation's reasons over them, and one of another type's context read in
        this call's frame raised ``KeyError: 'tokens'``, CI stop 80), and past dynamo's recompile limit the
        "compiled" policy would run eager and the test would check nothing."""
        torch._dynamo.reset()

    @staticmethod
    def noise_like(actions: Tensor, seed: int = 0) -> Tensor:
        return torch.randn(actions.shape, generator=torch.Generator().manual_seed(seed))

    # ---- the contract -----------------------------------------------------------------------------------------
    def test_is_a_flow_policy_whose_expert_parameters_hold_phi_s_and_leave_out_the_prefix(self, policy):
        assert isinstance(policy, FlowPolicy)
        phi_s = policy.target_time_embedding
        expert = {id(parameter) for parameter in policy.expert_parameters()}
        assert all(id(parameter) in expert for parameter in phi_s.parameters())
        assert 0 < len(expert) < len(list(policy.parameters())), "the prefix (VLM) is not among the expert parameters"
        # only phi_s's last layer starts at zero (weights and bias); the first keeps its normal init (SPEC 3)
        assert not phi_s.linear_out.weight.any() and not phi_s.linear_out.bias.any()
        assert phi_s.linear_in.weight.abs().sum() > 0

    def test_wrapping_changes_no_output_bit_at_init(self, policy, batch):
        observation, actions = batch
        noise = self.noise_like(actions)
        for steps in (1, 2):
            expected = self.reference_sample(observation, noise, steps)
            assert torch.equal(sample_actions(policy, observation, noise, SamplingMode(steps, jump=False)), expected)
        # phi_s starts at zero, so even the jump (s = 0) reproduces the unwrapped one-step sample bit for bit
        assert torch.equal(
            sample_actions(policy, observation, noise, SNAPFLOW_1), self.reference_sample(observation, noise, 1)
        )

    def test_velocity_keeps_the_noisy_actions_shape_and_contexts_select_rows(self, policy, batch):
        observation, actions = batch
        randomise_target_time(policy)
        generator = torch.Generator().manual_seed(1)
        x_t = torch.randn(actions.shape, generator=generator)
        t = torch.rand(self.batch_size, generator=generator)
        s = t * torch.rand(self.batch_size, generator=generator)
        with torch.no_grad():
            context = policy.encode(observation)
            velocity = policy.velocity(x_t, t, s, context)
            rows = policy.velocity(x_t[1:3], t[1:3], s[1:3], index_batch(context, slice(1, 3)))
            local = policy.velocity(x_t, t, t, context)
        assert velocity.shape == actions.shape and velocity.dtype == actions.dtype and torch.isfinite(velocity).all()
        # the objective scores its one-step rows on a row selection of the shared context
        assert rows.shape == (2, *actions.shape[1:]) and torch.allclose(rows, velocity[1:3], atol=1e-5)
        assert not torch.allclose(velocity, local), "the target time s must reach the velocity"

    @pytest.mark.parametrize("target_steps", [2, 4])
    def test_targets_are_built_without_gradient_and_one_gradient_pass_trains_every_row(
        self, policy, batch, target_steps
    ):
        observation, actions = batch
        calls = record_calls(policy)
        objective = SnapFlowObjective(target_steps=target_steps)
        output = objective(policy, observation, actions, generator=torch.Generator().manual_seed(0))
        one_step_rows = self.batch_size - objective.num_flow_matching(self.batch_size)
        assert calls["encode"] == [True], "the prefix is encoded once per objective call"
        *targets, trained = calls["velocity"]
        assert len(targets) == target_steps, "one no-grad pass per Euler step of the target"
        grid = torch.linspace(1, 0, target_steps + 1)
        for step, call in enumerate(targets):
            assert not call.grad_enabled and not call.output_requires_grad and call.rows == one_step_rows
            # the teacher velocity is the model's own marginal one: s = t, from t = 1 down the Euler grid
            assert torch.equal(call.s, call.t) and torch.allclose(call.t, grid[step].expand(one_step_rows))
        assert trained.grad_enabled and trained.output_requires_grad and trained.rows == self.batch_size
        fm = self.batch_size - one_step_rows
        assert torch.equal(trained.s[:fm], trained.t[:fm]), "flow-matching rows ask for the local velocity"
        assert (trained.t[fm:] == 1).all() and (trained.s[fm:] == 0).all(), "one-step rows jump from t = 1 to s = 0"
        assert output.loss.requires_grad and not output.consistency_loss.requires_grad

    def test_teacher_training_takes_one_gradient_pass_and_no_target_pass(self, policy, batch):
        observation, actions = batch
        calls = record_calls(policy)
        output = SnapFlowObjective(alpha=1.0)(policy, observation, actions, generator=torch.Generator().manual_seed(0))
        assert calls["encode"] == [True] and len(calls["velocity"]) == 1
        (call,) = calls["velocity"]
        assert call.grad_enabled and call.rows == self.batch_size and torch.equal(call.s, call.t)
        assert output.num_consistency == 0 and output.consistency_loss == 0

    def test_a_generator_reproduces_the_loss_and_its_gradients(self, batch):
        observation, actions = batch

        def loss_and_gradients(seed: int) -> tuple[Tensor, dict[str, Tensor]]:
            policy = randomise_target_time(self.build())
            policy.train()
            output = SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(seed))
            output.loss.backward()
            return output.loss.detach(), {name: p.grad for name, p in policy.named_parameters() if p.grad is not None}

        (loss, gradients), (again, gradients_again) = loss_and_gradients(5), loss_and_gradients(5)
        assert torch.equal(loss, again)
        assert gradients.keys() == gradients_again.keys() and len(gradients) > 0
        assert all(torch.equal(gradients[name], gradients_again[name]) for name in gradients), "gradients differ"
        assert not torch.equal(loss_and_gradients(6)[0], loss), "another seed draws other noise and times"

    def test_gradients_reach_exactly_the_expert_parameters_phi_s_included(self, policy, batch):
        observation, actions = batch
        trainable = {id(parameter) for parameter in policy.expert_parameters()}
        for parameter in policy.parameters():  # as the trainer freezes the prefix
            parameter.requires_grad_(id(parameter) in trainable)
        SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss.backward()
        for name, parameter in policy.named_parameters():
            if id(parameter) in trainable:
                assert parameter.grad is not None, f"{name} got no gradient"
            else:
                assert parameter.grad is None, f"{name} is frozen but got a gradient"
        # at step 0 phi_s's last layer is zero, so only it receives a non-zero gradient; Linear1 follows a step later
        phi_s = policy.target_time_embedding
        assert phi_s.linear_in.weight.grad is not None and phi_s.linear_out.weight.grad.abs().sum() > 0
        phi_s_ids = {id(parameter) for parameter in phi_s.parameters()}
        assert sum(p.grad.abs().sum() for p in policy.expert_parameters() if id(p) not in phi_s_ids) > 0, (
            "the expert learns too"
        )

    def test_save_load_round_trip_keeps_every_tensor_and_sample(self, policy, batch, tmp_path):
        randomise_target_time(policy)
        observation, actions = batch
        noise = self.noise_like(actions)
        expected = {mode: sample_actions(policy, observation, noise, mode) for mode in (SNAPFLOW_1, TEACHER_10)}
        self.save(policy, tmp_path / "saved")
        with self.loading():
            loaded = self.load(tmp_path / "saved")
        assert type(loaded) is type(policy)
        state, loaded_state = policy.state_dict(), loaded.state_dict()
        assert state.keys() == loaded_state.keys() and all(torch.equal(state[key], loaded_state[key]) for key in state)
        for mode, sample in expected.items():
            assert torch.equal(sample_actions(loaded, observation, noise, mode), sample), mode.name
        (tmp_path / "empty").mkdir()
        with pytest.raises(CheckpointError), self.loading():
            self.load(tmp_path / "empty")

    # up to ~60 s an architecture on CI's two cores: torch.compile's inductor compiles both the prefix pass and the
    # velocity, which is what is tested
    @pytest.mark.slow
    @pytest.mark.usefixtures("fresh_compiler")
    def test_the_compiled_fast_path_samples_what_eager_does(self, policy, batch, monkeypatch):
        from snapflow.inference import compile_policy

        if self.compile_backend != "inductor":
            monkeypatch.setattr(torch, "compile", functools.partial(torch.compile, backend=self.compile_backend))
        randomise_target_time(policy)
        observation, actions = batch
        noise = self.noise_like(actions)
        eager = {mode: sample_actions(policy, observation, noise, mode) for mode in (SNAPFLOW_1, TEACHER_10)}
        prefix, velocity = getattr(policy, "compiled_methods", ("encode", "velocity"))
        assert compile_policy(policy, "default") is policy
        assert {prefix, velocity} <= set(vars(policy)), "both the prefix pass and the velocity are replaced"
        for mode, expected in eager.items():
            # inductor fuses and reorders float32 arithmetic: equal within rounding, not bit for bit
            torch.testing.assert_close(sample_actions(policy, observation, noise, mode), expected, atol=1e-4, rtol=1e-4)

    @pytest.mark.slow
    @pytest.mark.usefixtures("fresh_compiler")
    def test_the_deploy_fast_path_runs_the_one_step_chunk_as_one_graph_within_its_bound(self, policy, batch):
        from torch._dynamo.utils import counters

        from snapflow.inference.deploy import DEPLOY_ACTION_BOUND
        from snapflow.inference.fast_paths import apply_fast_path

        randomise_target_time(policy)
        policy.eval()
        observation, actions = batch
        noise = self.noise_like(actions)
        eager = {mode: sample_actions(policy, observation, noise, mode) for mode in (SNAPFLOW_1, TEACHER_10)}
        assert apply_fast_path(policy, "deploy") is policy
        graphs = counters["stats"]["unique_graphs"]
        one_step = sample_actions(policy, observation, noise, SNAPFLOW_1)
        if self.deploy_graphs is not None:
            assert counters["stats"]["unique_graphs"] - graphs == self.deploy_graphs, (
                "the prefix and the jump, one graph"
            )
        for mode, fast in (
            (SNAPFLOW_1, one_step),
            (TEACHER_10, sample_actions(policy, observation, noise, TEACHER_10)),
        ):
            assert (fast - eager[mode]).abs().max().item() <= DEPLOY_ACTION_BOUND, mode.name


def contract_classes(base: type) -> Iterator[type]:
    """The test classes that inherit ``base``, at any depth (those of the modules imported so far)."""
    for subclass in base.__subclasses__():
        if subclass.__name__.startswith("Test"):
            yield subclass
        yield from contract_classes(subclass)
