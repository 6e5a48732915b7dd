"""The contract of every policy under SnapFlow, in the spirit of diffusers' ``SchedulerCommonTest``.

:class:`FlowPolicyContract` holds the checks; a subclass only says how to build, sample, save and load its policy.
Every LeRobot adapter (SmolVLA always; pi0 and pi0.5 where lerobot >= 0.5 is installed) runs them through
:class:`LeRobotAdapterContract`, which adds what only LeRobot has (its own sampler, training forward and action API),
and every built-in policy (MiniVLA, MLP) through :class:`BuiltinPolicyContract`. A new adapter or built-in policy
without a subclass here fails :func:`test_every_built_in_policy_runs_the_contract` /
:func:`test_every_lerobot_adapter_runs_the_contract`.

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
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch
from packaging.version import Version
from torch import Tensor, nn

from snapflow import NAIVE_1, SNAPFLOW_1, FlowPolicy, SamplingMode, SnapFlowObjective, SnapFlowPolicy, sample_actions
from snapflow.policies.checkpoint import CheckpointError, load_policy, policy_metadata, write_policy
from snapflow.policies.factory import POLICIES, default_config, make_model, make_processor
from snapflow.policies.normalization import NormalizationStats
from snapflow.protocol import index_batch, map_tensors
from tests.lerobot_tiny import PI_SKIP, TRANSFORMERS, randomise_target_time

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
    def test_the_compiled_fast_path_samples_what_eager_does(self, policy, batch):
        from snapflow.inference import compile_policy

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


# ---- the LeRobot adapters -------------------------------------------------------------------------------------


class LeRobotAdapterContract(FlowPolicyContract):
    """A LeRobot policy of ``policy_type`` under its adapter, built offline at tiny size (tests/lerobot_tiny.py)."""

    policy_type: ClassVar[str]

    @pytest.fixture(autouse=True)
    def _tiny_vlm(self, vlm_directory: Path) -> None:  # also skips the class where LeRobot is not installed
        self.vlm_directory = vlm_directory

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny import build_tiny_pi, build_tiny_smolvla

        return (
            build_tiny_smolvla(self.vlm_directory) if self.policy_type == "smolvla" else build_tiny_pi(self.policy_type)
        )

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        """``steps`` Euler steps by LeRobot's own sampler of ``lerobot`` (a policy, wrapped or not)."""
        from tests.lerobot_tiny import lerobot_sample

        return lerobot_sample(lerobot, observation, noise, steps)

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        """The flow-matching loss LeRobot's own training forward computes for these noise and times."""
        from tests.lerobot_tiny import model_inputs

        return lerobot.model.forward(*model_inputs(lerobot, observation), actions, noise, time).mean()

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """LeRobot's action API's chunk from ``noise`` (drawn by :meth:`noise_like` with seed 0)."""
        return lerobot.predict_action_chunk(observation, noise=noise)

    def build(self) -> nn.Module:
        from snapflow.adapters.lerobot import wrap_policy

        return wrap_policy(self.build_lerobot())

    def reference_sample(self, observation: Any, noise: Tensor, steps: int) -> Tensor:
        return self.lerobot_own_sample(self.build_lerobot(), observation, noise, steps)

    def make_batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        from tests.lerobot_tiny import tiny_batch

        batch = tiny_batch(self.batch_size)
        return batch, policy.action_targets(batch)

    def save(self, policy: nn.Module, directory: Path) -> None:
        from snapflow.adapters.lerobot import save_distilled

        save_distilled(policy, directory)

    def load(self, directory: Path) -> nn.Module:
        from snapflow.adapters.lerobot import load_distilled

        return load_distilled(directory)

    def loading(self) -> contextlib.AbstractContextManager:
        from tests.lerobot_tiny import tiny_pi_configs

        return tiny_pi_configs(self.policy_type) if self.policy_type in ("pi0", "pi05") else contextlib.nullcontext()

    # ---- what only LeRobot policies have ----------------------------------------------------------------------
    def test_cutting_the_prompts_padding_changes_no_chunk(self, policy, batch):
        from snapflow.adapters.lerobot.base import OBS_LANGUAGE_ATTENTION_MASK as MASK
        from snapflow.adapters.lerobot.base import OBS_LANGUAGE_TOKENS as TOKENS

        randomise_target_time(policy)
        observation, actions = batch
        if not policy.masks_prompt_padding:  # a policy that attends to its padding keeps it
            assert policy.without_prompt_padding(observation, multiple=1) is observation
            return
        mask, noise = observation[MASK], self.noise_like(actions)
        longest = int(mask.sum(dim=1).max())
        cut = policy.without_prompt_padding(observation, multiple=1)
        assert cut[MASK].shape[1] == cut[TOKENS].shape[1] == longest < mask.shape[1]
        for mode in (TEACHER_10, SNAPFLOW_1):  # padding is masked out everywhere: rounding apart, the same chunk
            torch.testing.assert_close(
                sample_actions(policy, cut, noise, mode), sample_actions(policy, observation, noise, mode)
            )
        assert policy.without_prompt_padding(observation, multiple=4)[MASK].shape[1] == min(
            -(-longest // 4) * 4, mask.shape[1]
        )
        left_padded = {**observation, MASK: mask.flip(1), TOKENS: observation[TOKENS].flip(1)}
        assert policy.without_prompt_padding(left_padded, multiple=1) is left_padded, "only right padding is cut"

    def test_lerobot_sampling_reads_s_as_t_so_phi_s_changes_only_the_jump(self, policy, batch):
        randomise_target_time(policy)
        noise = self.noise_like(batch[1])
        # LeRobot's own sampler passes a (B,) time, read as s = t: it is exactly our teacher mode
        assert torch.equal(
            sample_actions(policy, batch[0], noise, NAIVE_1),
            self.lerobot_own_sample(policy.policy, batch[0], noise, 1),
        )
        assert not torch.allclose(
            sample_actions(policy, batch[0], noise, SNAPFLOW_1), sample_actions(policy, batch[0], noise, NAIVE_1)
        )

    def test_loss_equals_a_hand_computation_from_the_policys_own_outputs(self, policy, batch):
        randomise_target_time(policy)
        observation, actions = batch
        lerobot = policy.policy
        noise, time = self.noise_like(actions), torch.rand(2, generator=torch.Generator().manual_seed(1))
        output = SnapFlowObjective()(policy, observation, actions, noise=noise, time=time)

        fm_rows = {key: value[:2] for key, value in observation.items()}
        sc_rows = {key: value[2:] for key, value in observation.items()}
        # FM branch: LeRobot's own joint training forward returns the elementwise squared errors
        fm = self.lerobot_own_flow_matching_loss(lerobot, fm_rows, actions[:2], noise[:2], time)
        # consistency target: two LeRobot Euler steps from x_1 land on x_1 - target
        target = noise[2:] - self.lerobot_own_sample(lerobot, sc_rows, noise[2:], 2)
        jump = policy.velocity(noise[2:], torch.ones(2), torch.zeros(2), policy.encode(sc_rows))
        sc = (jump - target).pow(2).mean()
        assert torch.allclose(output.flow_matching_loss, fm, atol=1e-5)
        assert torch.allclose(output.consistency_loss, sc, atol=1e-5)
        assert torch.allclose(output.loss, 0.5 * fm + 0.5 * 0.1 * sc, atol=1e-5)

    def test_the_frozen_vlm_pass_keeps_no_graph_even_where_the_vlm_could_learn(self, policy, batch):
        from tests.lerobot_tiny import model_inputs

        observation, actions = batch
        for parameter in policy.parameters():  # nothing frozen, not even what LeRobot's config freezes itself
            parameter.requires_grad_(True)
        leaves: list[Tensor] = []
        map_tensors(policy.encode(observation), leaves.append)
        assert leaves and not any(leaf.requires_grad for leaf in leaves), "the VLM's cache must carry no graph"
        SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss.backward()
        expert = {id(parameter) for parameter in policy.expert_parameters()}
        reached = sorted(
            name
            for name, parameter in policy.named_parameters()
            if id(parameter) not in expert and parameter.grad is not None
        )
        assert not reached, f"the VLM learned: {reached[:5]}"
        # the adapter hands LeRobot's model what LeRobot's own predict_action_chunk hands it
        for ours, theirs in zip(
            policy.model_inputs(observation), model_inputs(policy.policy, observation), strict=True
        ):
            if isinstance(ours, dict):
                pairs = [(ours[key], theirs[key]) for key in sorted(ours.keys() | theirs.keys())]
            elif isinstance(ours, (list, tuple)):
                pairs = list(zip(ours, theirs, strict=True))
            else:
                pairs = [(ours, theirs)]
            assert all(torch.equal(a, b) for a, b in pairs)

    def test_the_adapters_own_state_dict_holds_each_tensor_once(self, policy):
        # safetensors refuses tensors saved under two names: the adapter adds no second name, to phi_s or anything
        # else (LeRobot's own ties, as Florence-2's shared embedding, are saved once by LeRobot's writer)
        lerobot_names = {id(tensor): name for name, tensor in policy.policy.state_dict(keep_vars=True).items()}
        names: dict[int, list[str]] = {}
        for name, tensor in policy.state_dict(keep_vars=True).items():
            names.setdefault(id(tensor), []).append(name)
        assert all(len(aliases) == 1 or lerobot_names.get(key) for key, aliases in names.items())
        assert sum(len(aliases) for aliases in names.values()) == len(policy.policy.state_dict())
        state = policy.state_dict()
        assert sum("target_time_embedding" in key for key in state) == 4, "phi_s: two layers, weight and bias, once"

    def test_lerobot_action_api_samples_one_step_by_default_and_the_teacher_on_request(self, policy, batch, tmp_path):
        from snapflow.adapters.lerobot import load_distilled, save_distilled

        randomise_target_time(policy)
        save_distilled(policy, tmp_path / "distilled")
        with self.loading():
            reloaded = load_distilled(tmp_path / "distilled")
        observation, actions = batch
        noise = self.noise_like(actions)
        one_step = self.lerobot_chunk(reloaded.policy, observation, noise)
        assert torch.equal(one_step, sample_actions(policy, observation, noise, SNAPFLOW_1))
        assert reloaded.policy.select_action(observation).shape == (
            self.batch_size,
            4,
        )  # LeRobot's queue of n_action_steps actions
        reloaded.use_sampling_mode(TEACHER_10)
        teacher = self.lerobot_chunk(reloaded.policy, observation, noise)
        assert torch.equal(teacher, sample_actions(policy, observation, noise, TEACHER_10))
        assert not torch.allclose(teacher, one_step)

    @pytest.mark.slow
    def test_distillation_lowers_the_consistency_loss(self, policy):
        from tests.lerobot_tiny import tiny_batch

        parameters = policy.expert_parameters()
        trainable = {id(p) for p in parameters}
        for parameter in policy.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        observation = tiny_batch(batch_size=8)
        actions = policy.action_targets(observation)
        # a random tiny teacher has a large FM loss and a small consistency loss: weight the latter up so that a few
        # steps show it falling before the FM updates move the teacher's own two-step target
        objective = SnapFlowObjective(consistency_weight=1.0)
        noise, time = (
            torch.randn(8, 4, 4, generator=torch.Generator().manual_seed(1)),
            torch.rand(4, generator=torch.Generator().manual_seed(3)),
        )

        def consistency() -> float:
            with torch.no_grad():
                return objective(policy, observation, actions, noise=noise, time=time).consistency_loss.item()

        before = consistency()
        optimizer = torch.optim.AdamW(parameters, lr=1e-3)
        generator = torch.Generator().manual_seed(2)
        for _ in range(15):
            optimizer.zero_grad()
            objective(policy, observation, actions, generator=generator).loss.backward()
            optimizer.step()
        assert consistency() < 0.8 * before

    @pytest.mark.slow
    def test_bench_cli_times_a_distilled_lerobot_policy(self, policy, tmp_path):
        import json

        from snapflow.adapters.lerobot import save_distilled
        from snapflow.cli import main

        directory = save_distilled(policy, tmp_path / "distilled")
        output = tmp_path / "bench"
        with self.loading():
            assert (
                main(
                    [
                        "bench",
                        "--policy",
                        str(directory),
                        "--warmup",
                        "1",
                        "--repeats",
                        "2",
                        "--no-profile",
                        "--batch-sizes",
                        "1,2",
                        "--distill-batch-sizes",
                        "2",
                        "--output",
                        str(output),
                    ]
                )
                == 0
            )
        report = json.loads((output / "bench.json").read_text())
        assert report["details"]["policy_type"] == self.policy_type
        # the plan of a full run: a distillation step at batch 2 and the throughput at batch 1 and 2
        (step,) = report["distill_step"]["rows"]
        assert (
            step["batch_size"] == 2
            and 0 < step["step_ms_median"] <= step["step_ms_p90"]
            and step["peak_memory_gib"] > 0
        )
        assert list(report["throughput"]) == ["1", "2"] and 0 < report["jump_to_teacher_pass_ratio"]
        expert_tensors = {id(p): p for module in policy.expert_modules() for p in module.parameters()}  # each once
        expert = sum(parameter.numel() for parameter in expert_tensors.values())
        assert report["details"]["expert_parameters"] == expert
        assert report["details"]["parameters"] == sum(parameter.numel() for parameter in policy.parameters()) > expert
        latency = report["latency"]
        assert list(latency["modes"]) == ["teacher-10", "teacher-5", "teacher-2", "snapflow-1"]
        assert [latency["modes"][name]["nfe"] for name in latency["modes"]] == [10, 5, 2, 1]
        assert latency["prefix"]["repeats"] == 2 and latency["warmup"] == 1
        assert all(
            entry["denoising"]["repeats"] == 2 and 0 < entry["denoising"]["median_ms"] <= entry["denoising"]["p90_ms"]
            for entry in latency["modes"].values()
        )

        # a student type never distilled (as lerobot-train leaves one whose config says so) is timed at its naive
        # step, under that name, never as SnapFlow's
        from snapflow.benchmark.subjects import make_subject
        from snapflow.flow.modes import NAIVE_1

        (directory / "snapflow.json").unlink()
        config = json.loads((directory / "config.json").read_text())
        (directory / "config.json").write_text(json.dumps({**config, "distilled": False}))
        with self.loading():
            assert make_subject(str(directory), None, torch.device("cpu"), torch.float32).one_step == NAIVE_1


class TestSmolVLAAdapter(LeRobotAdapterContract):
    policy_type = "smolvla"
    # before transformers 5, SmolVLM sizes its patches' position ids by .item(), once per image: each breaks the graph
    deploy_graphs = 1 if TRANSFORMERS and TRANSFORMERS >= Version("5") else None


@PI_SKIP
class TestPI0Adapter(LeRobotAdapterContract):
    policy_type = "pi0"


@PI_SKIP
class TestPI05Adapter(LeRobotAdapterContract):
    policy_type = "pi05"


@PI_SKIP
class TestXVLAAdapter(LeRobotAdapterContract):
    """X-VLA predicts the clean chunk: LeRobot has no velocity of it, so its "own" velocity is written out here by
    hand from LeRobot's transformer, v = (x_t - a_hat) / t, and Euler-integrated on snapflow's grid."""

    policy_type = "xvla"
    deploy_graphs = None  # Florence-2's encoder counts the valid views by .item(): its graph breaks there

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_xvla import build_tiny_xvla

        return build_tiny_xvla()

    def load(self, directory: Path) -> nn.Module:
        from tests.lerobot_tiny_xvla import without_dropout

        return without_dropout(super().load(directory))

    @staticmethod
    def own_velocity(lerobot: nn.Module, encoded: dict, inputs: dict, x: Tensor, t: Tensor) -> Tensor:
        proprio, noisy = lerobot.model.action_space.preprocess(inputs["proprio"], x)
        clean = lerobot.model.transformer(
            domain_id=inputs["domain_id"], action_with_noise=noisy, proprio=proprio, t=t, **encoded
        )
        return (x - clean) / t[:, None, None]

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        inputs = lerobot._build_model_inputs(observation)
        grid = torch.linspace(1.0, 0.0, steps + 1)
        with torch.no_grad():
            encoded = lerobot.model.forward_vlm(inputs["input_ids"], inputs["image_input"], inputs["image_mask"])
            x = noise
            for t, t_next in zip(grid[:-1], grid[1:], strict=True):
                velocity = self.own_velocity(lerobot, encoded, inputs, x, t.expand(noise.shape[0]))
                x = x + (t_next - t).expand(noise.shape[0])[:, None, None] * velocity
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        inputs = lerobot._build_model_inputs(observation)
        encoded = lerobot.model.forward_vlm(inputs["input_ids"], inputs["image_input"], inputs["image_mask"])
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        return (self.own_velocity(lerobot, encoded, inputs, x_t, time) - (noise - actions)).pow(2).mean()

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        # X-VLA's action API takes no noise: it draws its own after the prefix, from the global generator
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(observation)

    def test_xvlas_own_one_step_sampler_is_the_naive_step(self, policy, batch):
        """X-VLA's own sampler at one step returns its clean prediction at t = 1: the naive step's x_1 - v."""
        randomise_target_time(policy)
        observation, actions = batch
        inputs = policy.policy._build_model_inputs(observation)
        torch.manual_seed(0)
        with torch.no_grad():
            own = policy.policy.model.generate_actions(**inputs, steps=1)
        naive = sample_actions(policy, observation, self.noise_like(actions), NAIVE_1)
        torch.testing.assert_close(own, naive, atol=1e-6, rtol=0)


@PI_SKIP
class TestMultiTaskDiTAdapter(LeRobotAdapterContract):
    """Multi-task DiT by flow matching runs its flow the other way (t = 0 noise): its "own" Euler is written out
    here by hand from LeRobot's transformer, on snapflow's grid, its velocity negated at LeRobot's time 1 - t."""

    policy_type = "multi_task_dit"
    deploy_graphs = None  # torchvision's crop and CLIP's pooling by token id split the prefix's graph

    @pytest.fixture(autouse=True)
    def _tiny_clip(self, clip_directory: Path) -> None:
        self.clip_directory = clip_directory

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_multi_task_dit import build_tiny_multi_task_dit

        return build_tiny_multi_task_dit(self.clip_directory)

    @staticmethod
    def encoded(lerobot: nn.Module, observation: Any) -> Tensor:
        from snapflow.adapters.lerobot.base import frozen_prefix_pass
        from tests.lerobot_tiny import model_inputs

        (batch,) = model_inputs(lerobot, observation)
        with frozen_prefix_pass(lerobot.observation_encoder):  # eval mode: the centre crop
            return lerobot.observation_encoder.encode(batch)

    @staticmethod
    def own_velocity(lerobot: nn.Module, conditioning: Tensor, x: Tensor, t: Tensor) -> Tensor:
        return -lerobot.noise_predictor(x, 1 - t, conditioning_vec=conditioning)

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        grid = torch.linspace(1.0, 0.0, steps + 1)
        with torch.no_grad():
            conditioning, x = self.encoded(lerobot, observation), noise
            for t, t_next in zip(grid[:-1], grid[1:], strict=True):
                velocity = self.own_velocity(lerobot, conditioning, x, t.expand(noise.shape[0]))
                x = x + (t_next - t).expand(noise.shape[0])[:, None, None] * velocity
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        velocity = self.own_velocity(lerobot, self.encoded(lerobot, observation), x_t, time)
        return (velocity - (noise - actions)).pow(2).mean()

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        from lerobot.policies.utils import populate_queues

        # its action API reads the observation queues select_action fills, and draws its own noise after the prefix
        lerobot.reset()
        batch = lerobot._prepare_batch({key: value for key, value in observation.items() if key != "action"})
        lerobot._queues = populate_queues(lerobot._queues, batch)
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(batch)

    def test_its_own_ten_euler_steps_are_the_teacher_mode_within_rounding(self, policy, batch):
        """LeRobot's own integrator (100 steps by default, 10 in the tiny config) runs the same flow as
        ``teacher-10``, on its own time grid."""
        observation, actions = batch
        lerobot = policy.policy
        with torch.no_grad():
            conditioning = self.encoded(lerobot, observation)
            torch.manual_seed(0)
            own = lerobot.objective.conditional_sample(lerobot.noise_predictor, self.batch_size, conditioning)
        teacher = sample_actions(policy, observation, self.noise_like(actions), TEACHER_10)
        torch.testing.assert_close(own, teacher, atol=1e-5, rtol=1e-5)

    def test_a_ddpm_trained_policy_is_refused_by_name(self):
        from lerobot.policies.multi_task_dit.modeling_multi_task_dit import MultiTaskDiTPolicy

        from snapflow.adapters.lerobot import wrap_policy
        from snapflow.errors import InvalidInputError

        config = self.build_lerobot().config
        config.objective = "diffusion"
        with pytest.raises(InvalidInputError, match="a DDPM denoiser has no velocity field"):
            wrap_policy(MultiTaskDiTPolicy(config))


# ---- the built-in policies ------------------------------------------------------------------------------------

STATE_DIM, ACTION_DIM = 39, 4  # Meta-World's
INSTRUCTIONS = ("push the puck to the goal", "open the drawer", "close the window")


class BuiltinPolicyContract(FlowPolicyContract):
    """A registered built-in policy (``snapflow.policies.factory.POLICIES[name]``) at a tiny size, with its processor
    (unit normalisation) making the observations, under :class:`snapflow.SnapFlowPolicy`."""

    name: ClassVar[str]
    sizes: ClassVar[dict[str, Any]]

    @pytest.fixture(autouse=True)
    def _configure(self) -> None:
        self.config = default_config(self.name, STATE_DIM, ACTION_DIM, INSTRUCTIONS, **self.sizes)
        state_entries = POLICIES[self.name].processor_class.state_entries(self.config, INSTRUCTIONS)
        stats = NormalizationStats([0.0] * state_entries, [1.0] * state_entries, [0.0] * ACTION_DIM, [1.0] * ACTION_DIM)
        self.processor = make_processor(self.config, stats, INSTRUCTIONS)

    def build(self, target_time: bool = True) -> SnapFlowPolicy:
        torch.manual_seed(0)
        return SnapFlowPolicy(self.stand_in_for_trained(make_model(self.config)), target_time=target_time)

    def stand_in_for_trained(self, model: nn.Module) -> nn.Module:
        """Make a random model's output depend on every input, as a trained one's does (default: it already does)."""
        return model

    def reference_sample(self, observation: Any, noise: Tensor, steps: int) -> Tensor:
        return sample_actions(self.build(target_time=False), observation, noise, SamplingMode(steps, jump=False))

    def make_batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        generator = np.random.default_rng(0)
        images = (
            generator.integers(
                0, 256, (self.batch_size, self.processor.image_size, self.processor.image_size, 3), dtype=np.uint8
            )
            if self.processor.image_size
            else None
        )
        states = generator.standard_normal((self.batch_size, STATE_DIM)).astype(np.float32)
        observation = self.processor.observation(
            states, [INSTRUCTIONS[row % len(INSTRUCTIONS)] for row in range(self.batch_size)], images
        )
        actions = torch.randn(
            self.batch_size,
            self.processor.chunk_length,
            self.processor.action_dim,
            generator=torch.Generator().manual_seed(2),
        )
        return observation, actions

    def save(self, policy: nn.Module, directory: Path) -> None:
        directory.mkdir()
        write_policy(directory, policy, policy_metadata(policy, self.processor, stage="snapflow"))

    def load(self, directory: Path) -> nn.Module:
        return load_policy(directory).policy

    def test_checkpoint_names_the_registered_policy_and_rebuilds_its_classes(self, policy, tmp_path):
        self.save(policy, tmp_path / "saved")
        loaded = load_policy(tmp_path / "saved")
        entry = POLICIES[self.name]
        assert loaded.metadata["policy"] == self.name and loaded.metadata["target_time"] is True
        assert type(loaded.policy.model) is entry.model_class and type(loaded.processor) is entry.processor_class
        assert loaded.processor.config == self.config and loaded.processor.instructions == INSTRUCTIONS


class TestMiniVLAPolicy(BuiltinPolicyContract):
    name = "minivla"
    sizes = dict(
        chunk_length=4,
        prefix_width=32,
        expert_width=32,
        num_layers=1,
        num_heads=2,
        head_dim=16,
        use_image=True,
        image_size=32,
        patch_size=16,
    )

    def stand_in_for_trained(self, model: nn.Module) -> nn.Module:
        # MiniVLA starts its expert blocks as the identity (adaRMS scale, shift and gates at zero, as pi0.5's): time and
        # prefix reach the velocity only once those projections have trained
        generator = torch.Generator().manual_seed(3)
        with torch.no_grad():
            for name, parameter in model.named_parameters():
                if "modulation" in name:
                    parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))
        return model


class TestMLPPolicy(BuiltinPolicyContract):
    name = "mlp"
    sizes = dict(chunk_length=4, hidden_dim=32, time_embedding_dim=16)


def _contract_classes(base: type) -> Iterator[type]:
    for subclass in base.__subclasses__():
        if subclass.__name__.startswith("Test"):
            yield subclass
        yield from _contract_classes(subclass)


def test_every_built_in_policy_runs_the_contract():
    assert sorted(cls.name for cls in _contract_classes(BuiltinPolicyContract)) == sorted(POLICIES)


def test_every_lerobot_adapter_runs_the_contract():
    pytest.importorskip(
        "lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it"
    )
    from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES

    assert sorted(cls.policy_type for cls in _contract_classes(LeRobotAdapterContract)) == sorted(LEROBOT_POLICY_TYPES)
