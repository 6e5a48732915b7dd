"""The contract every distillation objective keeps, in the spirit of diffusers' ``SchedulerCommonTest``.

:class:`ObjectiveContract` holds the tests; each objective (and each variant worth keeping honest) is one subclass
naming its registry entry, its options and how many no-grad velocity passes its one-step target costs. Every
registered objective must have a subclass. The tests run on both built-in policies, the MLP (tensor context) and
MiniVLA (dict observation and cached-prefix context), except the row split's cases, which run on the MLP. The math
of each objective is checked by hand in test_objective.py, test_targets.py and test_baselines.py.
"""

from __future__ import annotations

from typing import Any, ClassVar

import pytest
import torch
from torch import Tensor

from snapflow.flow import interpolate
from snapflow.nn import SnapFlowPolicy
from snapflow.objective import OBJECTIVES, LossOutput, TwoBranchObjective, make_objective
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor
from snapflow.policies.normalization import NormalizationStats
from tests.helpers import ACTION_DIM, CHUNK, OBSERVATION_DIM, RecordingPolicy, make_model, randomise_target_time

MINIVLA = MiniVLAConfig(
    state_dim=6,
    action_dim=ACTION_DIM,
    chunk_length=CHUNK,
    prefix_width=16,
    expert_width=16,
    num_layers=1,
    num_heads=2,
    head_dim=8,
    max_instruction_tokens=4,
)
INSTRUCTIONS = ["push the puck", "open the door", "close the window"]


def make_problem(kind: str, batch_size: int, seed: int = 7) -> tuple[SnapFlowPolicy, Any, Tensor]:
    """A student whose velocity depends on s and t, with an observation batch and action chunks of ``batch_size``."""
    generator = torch.Generator().manual_seed(seed)
    actions = torch.randn(batch_size, CHUNK, ACTION_DIM, generator=generator)
    if kind == "mlp":
        observation = torch.randn(batch_size, OBSERVATION_DIM, generator=generator)
        return randomise_target_time(SnapFlowPolicy(make_model())), observation, actions
    torch.manual_seed(0)
    model = MiniVLA(MINIVLA)
    with torch.no_grad():  # zero-initialised adaptive norms would ignore time
        for name, parameter in model.named_parameters():
            if "modulation" in name:
                parameter.normal_(0, 0.1, generator=generator)
    stats = NormalizationStats([0.0] * 6, [1.0] * 6, [0.0] * ACTION_DIM, [1.0] * ACTION_DIM)
    processor = MiniVLAProcessor(MINIVLA, stats)
    states = torch.randn(batch_size, 6, generator=generator).numpy()
    observation = processor.observation(states, [INSTRUCTIONS[row % len(INSTRUCTIONS)] for row in range(batch_size)])
    return randomise_target_time(SnapFlowPolicy(model)), observation, actions


def gradient_leaves(loss: Tensor) -> list[Tensor]:
    """Every tensor the backward pass of ``loss`` would accumulate a gradient into."""
    leaves, seen, pending = [], {}, [loss.grad_fn]
    while pending:
        node = pending.pop()
        if node is None or id(node) in seen:
            continue
        seen[id(node)] = node  # held, so that no later node can reuse its id
        if hasattr(node, "variable"):  # an AccumulateGrad node
            leaves.append(node.variable)
        pending.extend(next_node for next_node, _ in node.next_functions)
    return leaves


def ids(tensors: Any) -> set[int]:
    return {id(tensor) for tensor in tensors}


@pytest.fixture(params=["mlp", "minivla"])
def policy_kind(request: pytest.FixtureRequest) -> str:
    return request.param


class ObjectiveContract:
    """What every objective must do, whatever its one-step target; subclasses set the three class variables."""

    name: ClassVar[str]  # its key in snapflow.objective.OBJECTIVES
    options: ClassVar[dict[str, Any]] = {}  # keyword options for make_objective
    target_passes: ClassVar[int]  # no-grad velocity passes of the online policy per call (at the end of training)
    samples_per_row: ClassVar[int] = 1  # rows of the gradient pass per one-step row (more: a set-level term's samples)
    without_set_term: ClassVar[dict[str, Any]] = {}  # options that zero a set-level term, for the loss's combination

    def build(self, **changes: Any) -> TwoBranchObjective:
        return make_objective(self.name, **{**self.options, **changes})

    def run(
        self, kind: str, batch_size: int = 6, seed: int = 0, **changes: Any
    ) -> tuple[LossOutput, RecordingPolicy, SnapFlowPolicy]:
        """One call of a freshly built objective on a fresh problem, its draws made from a generator seeded ``seed``."""
        policy, observation, actions = make_problem(kind, batch_size)
        recorder = RecordingPolicy(policy)
        output = self.build(**changes)(recorder, observation, actions, generator=torch.Generator().manual_seed(seed))
        return output, recorder, policy

    def test_targets_take_no_gradient_and_one_pass_over_all_rows_does(self, policy_kind: str):
        """The prefix is encoded once; the target's passes run without autograd; then exactly one gradient-enabled
        pass covers every row of the batch, flow-matching and one-step rows together."""
        output, recorder, _ = self.run(policy_kind)
        assert recorder.encodes == 1, "the context must be computed once per call and serve every pass"
        assert len(recorder.calls) == self.target_passes + 1
        *targets, gradient_pass = recorder.calls
        for call in targets:
            assert not call.grad_enabled and not call.output.requires_grad
        assert gradient_pass.grad_enabled and gradient_pass.output.requires_grad
        assert output.num_flow_matching + output.num_consistency == 6
        rows = output.num_flow_matching + self.samples_per_row * output.num_consistency
        assert gradient_pass.x.shape == (rows, CHUNK, ACTION_DIM)

    def test_loss_output_shapes_types_and_combination(self, policy_kind: str):
        """A scalar loss with a graph, detached finite scalar parts, integer row counts, and
        loss = alpha * L_FM + (1 - alpha) * lambda * L_one-step."""
        output, _, _ = self.run(policy_kind, alpha=0.5, consistency_weight=0.3, **self.without_set_term)
        assert isinstance(output, LossOutput)
        assert output.loss.shape == () and output.loss.requires_grad and torch.isfinite(output.loss)
        for part in (output.flow_matching_loss, output.consistency_loss):
            assert part.shape == () and not part.requires_grad and torch.isfinite(part) and part > 0
        assert type(output.num_flow_matching) is int and type(output.num_consistency) is int
        assert (output.num_flow_matching, output.num_consistency) == (3, 3)
        combined = 0.5 * output.flow_matching_loss + 0.5 * 0.3 * output.consistency_loss
        assert torch.allclose(output.loss.detach(), combined, rtol=1e-6)

    def test_same_seed_gives_a_bit_identical_loss_and_another_seed_another(self, policy_kind: str):
        """Every draw (noise, times, the method's own randomness) comes from the generator given."""
        first, again, other = (self.run(policy_kind, seed=seed)[0] for seed in (0, 0, 1))
        for name in ("loss", "flow_matching_loss", "consistency_loss"):
            assert torch.equal(getattr(first, name), getattr(again, name)), name
        assert not torch.equal(first.loss, other.loss)

    @pytest.mark.parametrize(
        "alpha, batch_size, n_fm",
        [
            (0.5, 6, 3),
            (0.5, 5, 3),
            (0.25, 6, 2),
            (0.3, 10, 3),
            (0.5, 2, 1),
            (0.1, 4, 1),
            (0.9, 4, 3),
        ],
    )
    def test_rows_split_round_alpha_b_with_both_branches_present(self, alpha: float, batch_size: int, n_fm: int):
        """The first round(alpha * B) rows (half up, at least one of each kind) are flow matching at s = t on the
        straight path; the others ask for a jump s < t from a time in (0, 1]."""
        policy, observation, actions = make_problem("mlp", batch_size)
        objective = self.build(alpha=alpha)
        assert objective.num_flow_matching(batch_size) == n_fm
        generator = torch.Generator().manual_seed(3)
        noise, time = torch.randn(actions.shape, generator=generator), torch.rand(n_fm, generator=generator)
        recorder = RecordingPolicy(policy)
        output = objective(recorder, observation, actions, noise=noise, time=time, generator=generator)
        assert (output.num_flow_matching, output.num_consistency) == (n_fm, batch_size - n_fm)
        gradient_pass = recorder.calls[-1]
        assert torch.equal(gradient_pass.t[:n_fm], time) and torch.equal(gradient_pass.s[:n_fm], time)
        assert torch.allclose(gradient_pass.x[:n_fm], interpolate(actions[:n_fm], noise[:n_fm], time))
        t, s = gradient_pass.t[n_fm:], gradient_pass.s[n_fm:]
        assert torch.all(s < t) and torch.all(s >= 0) and torch.all(t > 0) and torch.all(t <= 1)

    def test_alpha_one_is_plain_flow_matching(self, policy_kind: str):
        """alpha = 1: one pass, no one-step row, and the loss is || F(x_t, t, s=t) - (eps - a) ||^2 by hand."""
        policy, observation, actions = make_problem(policy_kind, 6)
        generator = torch.Generator().manual_seed(3)
        noise, time = torch.randn(actions.shape, generator=generator), torch.rand(6, generator=generator)
        recorder = RecordingPolicy(policy)
        output = self.build(alpha=1.0)(recorder, observation, actions, noise=noise, time=time)
        assert len(recorder.calls) == 1 and (output.num_flow_matching, output.num_consistency) == (6, 0)
        assert output.consistency_loss == 0
        x_t = (1 - time[:, None, None]) * actions + time[:, None, None] * noise
        prediction = policy.velocity(x_t, time, time, policy.encode(observation))
        assert torch.allclose(output.loss, ((prediction - (noise - actions)) ** 2).mean(), atol=1e-6)

    def test_alpha_zero_is_the_one_step_branch_alone(self, policy_kind: str):
        """alpha = 0: every row is a one-step row and the loss is lambda * L_one-step."""
        output, recorder, _ = self.run(policy_kind, alpha=0.0, consistency_weight=0.3, **self.without_set_term)
        assert (output.num_flow_matching, output.num_consistency) == (0, 6) and output.flow_matching_loss == 0
        assert torch.all(recorder.calls[-1].s < recorder.calls[-1].t)
        assert torch.allclose(output.loss.detach(), 0.3 * output.consistency_loss)

    def test_gradients_reach_the_policy_parameters_only_and_are_finite(self, policy_kind: str):
        """The loss's graph ends in the policy's own parameters and in nothing else (no target network, no input),
        among them every parameter distillation trains (phi_s included); every gradient is finite."""
        output, _, policy = self.run(policy_kind)
        reached = ids(gradient_leaves(output.loss))
        # MiniVLA's last prefix layer feeds the expert its keys and values only, so its output projection and MLP
        # are out of the graph; they are prefix parameters, frozen in distillation
        assert ids(policy.expert_parameters()) <= reached <= ids(policy.parameters())
        output.loss.backward()
        for name, parameter in policy.named_parameters():
            if id(parameter) in reached:
                assert parameter.grad is not None and torch.isfinite(parameter.grad).all(), name
            else:
                assert parameter.grad is None, name
        assert policy.target_time_embedding.linear_out.weight.grad.abs().sum() > 0

    def test_registry_builds_it_and_names_an_unknown_option(self):
        """make_objective(name, **options) is the registered class built with those options; an option the objective
        does not take is a ValueError naming it."""
        objective = self.build()
        assert type(objective) is OBJECTIVES[self.name].objective_class
        assert objective == OBJECTIVES[self.name].objective_class(**self.options)
        with pytest.raises(ValueError, match=rf"the {self.name} objective takes no option bogus"):
            make_objective(self.name, **self.options, bogus=1)


class TestSnapFlow(ObjectiveContract):
    """The paper's objective: the two-step Euler shortcut target."""

    name = "snapflow"
    target_passes = 2


class TestSnapFlowFourEulerSteps(ObjectiveContract):
    """A K = 4 Euler target: one more no-grad pass per extra step."""

    name = "snapflow"
    options = {"target_steps": 4}
    target_passes = 4


class TestSnapFlowSchedule(ObjectiveContract):
    """K raised over training; a call without progress is at the end of training, K = 8."""

    name = "snapflow"
    options = {"target_steps": (2, 4, 8)}
    target_passes = 8


class TestSnapFlowConditionalVelocity(ObjectiveContract):
    """The paper's ablation: the target is eps - a, computed without any pass of the policy."""

    name = "snapflow"
    options = {"teacher_velocity": "conditional"}
    target_passes = 0


class TestBootstrappedSnapFlow(ObjectiveContract):
    """Two no-grad half-jumps per row, whatever K."""

    name = "snapflow-bootstrap"
    options = {"target_steps": 8}
    target_passes = 2


class TestEnergySnapFlow(ObjectiveContract):
    """SnapFlow's two-step target, and two more one-step samples per row in the gradient pass for its energy term."""

    name = "snapflow-energy"
    options = {"energy_samples": 3}
    target_passes = 2
    samples_per_row = 3
    without_set_term = {"energy_weight": 0.0}


class TestConsistencyDistillation(ObjectiveContract):
    """One teacher Euler step on the online policy; the EMA target network is a copy whose pass is not the policy's."""

    name = "consistency-distillation"
    target_passes = 1


class TestMeanFlow(ObjectiveContract):
    """The instantaneous velocity, then one forward-mode JVP through the policy."""

    name = "meanflow"
    target_passes = 2


def test_every_registered_objective_keeps_the_contract():
    """A new entry in OBJECTIVES needs a contract subclass here, and every contract names a registered objective."""
    assert {contract.name for contract in ObjectiveContract.__subclasses__()} == set(OBJECTIVES)
    assert all(issubclass(entry.objective_class, TwoBranchObjective) for entry in OBJECTIVES.values())
