"""A pretrained LeRobot checkpoint pads its chunks to ``max_action_dim`` (pi0's 32 for a 7-D arm), and its own loss
leaves that padding out: pi0, pi0.5, X-VLA's ``auto`` space and SmolVLA from LeRobot 0.5.1 cut their losses to the
dataset's action width. The objective weighs the same entries, checked here against the policy's own training loss
on the same noise and times and against the consistency loss written out by hand."""

from __future__ import annotations

from importlib.metadata import version

import pytest
import torch
from packaging.version import Version
from torch import Tensor, nn

from snapflow import SnapFlowObjective
from tests.lerobot_tiny import PI_SKIP, TINY_POLICY_SIZES, randomise_target_time, tiny_batch

ACTION_DIM = 3  # one column under the tiny configs' max_action_dim: the chunk's last column is padding
TYPES = ["smolvla", pytest.param("pi0", marks=PI_SKIP), pytest.param("pi05", marks=PI_SKIP)]


def build(policy_type: str, vlm_directory) -> nn.Module:
    from tests.lerobot_tiny import build_tiny_pi, build_tiny_smolvla
    from tests.lerobot_tiny_xvla import build_tiny_xvla

    if policy_type == "smolvla":
        return build_tiny_smolvla(vlm_directory, action_dim=ACTION_DIM)
    if policy_type == "xvla":
        return build_tiny_xvla(action_dim=ACTION_DIM)
    return build_tiny_pi(policy_type, action_dim=ACTION_DIM)


def weighed_width(policy_type: str) -> int:
    """How many columns of the padded chunk the type's own loss weighs, as LeRobot's code reads."""
    if policy_type == "smolvla" and Version(version("lerobot")) < Version("0.5.1"):
        return TINY_POLICY_SIZES["max_action_dim"]  # 0.4.4's SmolVLA cuts its losses at max_action_dim
    return ACTION_DIM


def own_flow_matching_loss(lerobot: nn.Module, batch: dict[str, Tensor], noise: Tensor, time: Tensor) -> Tensor:
    """The policy's own training loss (its ``forward``) with these noise and times in place of its own draws."""
    if lerobot.config.type == "smolvla":
        return lerobot.forward(batch, noise=noise, time=time)[0]
    model = lerobot.model  # pi0 / pi0.5 draw both inside; hand them ours
    model.sample_noise, model.sample_time = (lambda *_: noise), (lambda *_: time)
    try:
        return lerobot.forward(batch)[0]
    finally:
        del model.sample_noise, model.sample_time


def padded_batch(policy: nn.Module) -> tuple[dict[str, Tensor], Tensor]:
    batch = tiny_batch(4)
    batch["action"] = batch["action"][..., :ACTION_DIM]
    actions = policy.action_targets(batch)
    assert actions.shape[-1] == TINY_POLICY_SIZES["max_action_dim"] and not actions[..., ACTION_DIM:].any()
    return batch, actions


def consistency_by_hand(policy: nn.Module, observation: dict, noise: Tensor, width: int) -> Tensor:
    """The one-step rows' loss over ``width`` columns: the jump from x_1 against two teacher Euler steps."""
    ones, halves = torch.ones(2), torch.full((2,), 0.5)
    with torch.no_grad():
        context = policy.encode(observation)
        x_half = noise - 0.5 * policy.velocity(noise, ones, ones, context)
        x_0 = x_half - 0.5 * policy.velocity(x_half, halves, halves, context)
        jump = policy.velocity(noise, ones, torch.zeros(2), context)
    return (jump - (noise - x_0))[..., :width].pow(2).mean()


@pytest.mark.parametrize("policy_type", TYPES)
def test_the_objective_weighs_the_action_width_the_policys_own_loss_weighs(policy_type, vlm_directory):
    from snapflow.adapters.lerobot import wrap_policy

    policy = randomise_target_time(wrap_policy(build(policy_type, vlm_directory)))
    batch, actions = padded_batch(policy)
    width = weighed_width(policy_type)
    weights = policy.action_weights(batch)
    assert weights is None if width == actions.shape[-1] else weights.tolist() == [True] * width + [False]
    noise = torch.randn(actions.shape, generator=torch.Generator().manual_seed(0))
    time = torch.rand(2, generator=torch.Generator().manual_seed(1))
    output = SnapFlowObjective()(policy, batch, actions, noise=noise, time=time)

    first, last = ({key: value[rows] for key, value in batch.items()} for rows in (slice(None, 2), slice(2, None)))
    with torch.no_grad():
        own = own_flow_matching_loss(policy.policy, first, noise[:2], time)
    torch.testing.assert_close(output.flow_matching_loss, own, atol=1e-5, rtol=1e-5)
    sc = consistency_by_hand(policy, last, noise[2:], width)
    torch.testing.assert_close(output.consistency_loss, sc, atol=1e-5, rtol=1e-5)
    if width < actions.shape[-1]:  # the padding's error is not nothing: weighing it would have changed the loss
        everything = consistency_by_hand(policy, last, noise[2:], actions.shape[-1])
        assert not torch.allclose(everything, sc, atol=1e-4)


@PI_SKIP
def test_x_vlas_auto_space_leaves_its_padded_width_out_and_its_student_learns_only_the_real_one(vlm_directory):
    """X-VLA's own loss draws its noise inside: its ``auto`` space's MSE on the real width is checked by the
    gradient instead: the padded column of the velocity gets none."""
    from snapflow.adapters.lerobot import wrap_policy

    policy = randomise_target_time(wrap_policy(build("xvla", vlm_directory)))
    batch, actions = padded_batch(policy)
    assert policy.action_weights(batch).tolist() == [True] * ACTION_DIM + [False]
    predictions: list[Tensor] = []
    velocity = policy.velocity

    def kept_velocity(*inputs: Tensor) -> Tensor:  # the pass the loss differentiates keeps its gradient
        prediction = velocity(*inputs)
        if prediction.requires_grad:
            prediction.retain_grad()
            predictions.append(prediction)
        return prediction

    policy.velocity = kept_velocity
    SnapFlowObjective()(policy, batch, actions, generator=torch.Generator().manual_seed(0)).loss.backward()
    (prediction,) = predictions
    assert prediction.grad[..., ACTION_DIM:].abs().max() == 0
    assert prediction.grad[..., :ACTION_DIM].ne(0).all()
