"""MiniVLA: prefix cache separation, bit-identical wrapping, and the SnapFlow objective through it."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from snapflow.flow import UniformTimeSampler
from snapflow.nn import SnapFlowPolicy
from snapflow.objective import SnapFlowObjective
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor
from snapflow.policies.normalization import NormalizationStats

CONFIG = MiniVLAConfig(
    state_dim=6,
    action_dim=3,
    chunk_length=4,
    prefix_width=32,
    expert_width=32,
    num_layers=2,
    num_heads=2,
    head_dim=8,
    max_instruction_tokens=6,
)
STATS = NormalizationStats([0.0] * 6, [1.0] * 6, [0.0] * 3, [1.0] * 3)


def _observation(batch: int = 4) -> dict[str, torch.Tensor]:
    processor = MiniVLAProcessor(CONFIG, STATS)
    generator = torch.Generator().manual_seed(0)
    states = torch.randn(batch, 6, generator=generator).numpy()
    return processor.observation(states, ["push the puck to the goal", "open the door"] * (batch // 2))


def _randomise_modulation(model: MiniVLA) -> None:
    """Zero-initialised adaptive norms ignore time at init; a trained policy does not."""
    with torch.no_grad():
        for name, parameter in model.named_parameters():
            if "modulation" in name:
                parameter.normal_(0, 0.1)


def test_tokenizer_is_stable_and_pads():
    """Words hash to ids independently of case and punctuation; padding is id 0 and masked out."""
    processor = MiniVLAProcessor(CONFIG, STATS)
    tokens, mask = processor.tokenize(["Push the puck!", "push THE puck"])
    assert torch.equal(tokens[0], tokens[1]) and mask[0].sum() == 3 and tokens[0, 3:].eq(0).all()


def test_cached_prefix_gives_the_same_velocity_as_recomputing_it():
    """A denoising pass leaves the cached prefix intact, and the velocity reads the instruction through it."""
    torch.manual_seed(0)
    model = MiniVLA(CONFIG)
    _randomise_modulation(model)
    observation = _observation()
    x, t = torch.randn(4, 4, 3), torch.rand(4)
    cached = model.encode(observation)
    first = model.velocity_from_time_embedding(x, model.embed_time(t), cached)
    second = model.velocity_from_time_embedding(torch.randn(4, 4, 3), model.embed_time(torch.rand(4)), cached)
    again = model.velocity_from_time_embedding(x, model.embed_time(t), model.encode(observation))
    assert torch.equal(first, again), "a denoising pass must not alter the cached prefix"
    assert not torch.allclose(first, second)
    # the velocity depends on the instruction through the cache
    other = dict(observation, tokens=observation["tokens"].flip(0), token_mask=observation["token_mask"].flip(0))
    assert not torch.allclose(first, model.velocity_from_time_embedding(x, model.embed_time(t), model.encode(other)))


def test_wrapping_minivla_is_bit_identical_and_distillation_leaves_the_prefix_alone():
    """The wrapped student is the teacher bit for bit; distilling its expert_parameters() moves the action expert
    and phi_s and not one prefix ("VLM") weight."""
    torch.manual_seed(0)
    model = MiniVLA(CONFIG)
    _randomise_modulation(model)
    teacher = SnapFlowPolicy(copy.deepcopy(model), target_time=False)
    student = SnapFlowPolicy(copy.deepcopy(model))
    observation = _observation()
    x = torch.randn(4, 4, 3)
    for t_value in (1.0, 0.5, 0.2):
        t = torch.full((4,), t_value)
        assert torch.equal(
            student.velocity(x, t, torch.zeros(4), student.encode(observation)),
            teacher.velocity(x, t, t, teacher.encode(observation)),
        )
    prefix = {id(p) for p in student.model.prefix_parameters()}
    trainable = student.expert_parameters()
    assert {id(p) for p in trainable} == {id(p) for p in student.parameters()} - prefix
    before = {name: p.detach().clone() for name, p in student.named_parameters()}
    optimizer = torch.optim.Adam(trainable, lr=1e-3)
    objective = SnapFlowObjective(time_sampler=UniformTimeSampler())
    for _ in range(3):
        optimizer.zero_grad()
        objective(student, observation, torch.randn(4, 4, 3)).loss.backward()
        optimizer.step()
    updated = [
        name
        for name, p in student.named_parameters()
        if id(p) not in prefix and p.grad is not None and p.grad.abs().sum() > 0
    ]
    assert len(updated) >= len(trainable) // 2, "most of the expert should receive gradient"
    for name in updated:
        assert not torch.equal(before[name], student.get_parameter(name)), f"{name} had a gradient but did not move"
    assert all(torch.equal(before[n], p) for n, p in student.named_parameters() if id(p) in prefix)
    phi_s_out = "target_time_embedding.linear_out.weight"
    assert not torch.equal(before[phi_s_out], student.get_parameter(phi_s_out))


def test_shape_errors_name_the_expected_shape():
    """A state or a noisy action chunk of the wrong shape is refused with the shape expected."""
    model = MiniVLA(CONFIG)
    observation = _observation()
    with pytest.raises(ValueError, match=r"state must have shape \(B, 6\)"):
        model.encode(dict(observation, state=torch.zeros(4, 7)))
    with pytest.raises(ValueError, match=r"noisy actions must have shape \(B, 4, 3\)"):
        model.velocity_from_time_embedding(
            torch.zeros(4, 5, 3), model.embed_time(torch.rand(4)), model.encode(observation)
        )


def test_a_proprioceptive_policy_reads_the_leading_state_entries_only():
    """state_dim = 4 with a camera reads the hand and gripper entries and leaves the rest of the state to the image."""
    config = MiniVLAConfig(state_dim=4, use_image=True, image_size=32)
    processor = MiniVLAProcessor(config, NormalizationStats([0.0] * 4, [1.0] * 4, [0.0] * 4, [1.0] * 4))
    states = np.arange(2 * 39, dtype=np.float32).reshape(2, 39)
    images = np.zeros((2, 32, 32, 3), dtype=np.uint8)
    batch = processor.observation(states, ["reach", "push"], images)
    assert torch.equal(batch["state"], torch.from_numpy(states[:, :4]))
    assert batch["image"].shape == (2, 3, 32, 32) and processor.image_size == 32
    with pytest.raises(ValueError, match=r"states must have shape \(batch, >= 4\)"):
        processor.observation(states[:, :3], ["reach", "push"], images)
    with pytest.raises(ValueError, match="use_image=True, so every observation needs an image"):
        processor.observation(states, ["reach", "push"])
