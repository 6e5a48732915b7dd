"""MiniVLA's convolutional camera encoder: the spatial softmax and the random shift against the math written out,
several cameras through the processor and the model, and a small learning problem read from pixels only."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor
from snapflow.policies.minivla.vision import ConvEncoder, SpatialSoftmax, random_shift
from snapflow.policies.normalization import NormalizationStats

CONFIG = MiniVLAConfig(
    state_dim=2,
    action_dim=2,
    chunk_length=2,
    prefix_width=32,
    expert_width=32,
    num_layers=1,
    num_heads=2,
    head_dim=16,
    max_instruction_tokens=4,
    use_image=True,
    image_size=32,
    image_encoder="conv",
    extra_cameras=("image2",),
    keypoints=4,
    conv_width=8,
    random_shift=2,
)
STATS = NormalizationStats([0.0] * 2, [1.0] * 2, [0.0] * 2, [1.0] * 2)


def test_random_shift_is_a_crop_of_the_border_padded_image_at_an_offset_within_the_pad():
    torch.manual_seed(0)
    images = torch.rand(6, 3, 8, 8)
    shifted = random_shift(images, 2)
    padded = F.pad(images, (2, 2, 2, 2), mode="replicate")
    offsets = set()
    for sample in range(6):
        matches = [
            (row, column)
            for row in range(5)
            for column in range(5)
            if torch.equal(shifted[sample], padded[sample, :, row : row + 8, column : column + 8])
        ]
        assert matches, f"sample {sample} is no crop of its padded image"
        offsets.add(matches[0])
    assert len(offsets) > 1, "each sample draws its own shift"
    assert torch.equal(random_shift(images, 0), images)


def test_spatial_softmax_gives_each_maps_expected_position_and_the_features_there():
    torch.manual_seed(0)
    features = torch.randn(2, 3, 4, 5)
    pool = SpatialSoftmax(3, keypoints=2)
    tokens = pool(features)
    logits = torch.einsum("kc,bchw->bkhw", pool.maps.weight[:, :, 0, 0], features) + pool.maps.bias[:, None, None]
    weights = logits.flatten(2).softmax(-1).view(2, 2, 4, 5)
    xs, ys = torch.linspace(-1, 1, 5), torch.linspace(-1, 1, 4)
    expected_x = (weights * xs[None, None, None, :]).sum((2, 3))
    expected_y = (weights * ys[None, None, :, None]).sum((2, 3))
    expected_features = torch.einsum("bkhw,bchw->bkc", weights, features)
    assert tokens.shape == (2, 2, 2 + 3)
    torch.testing.assert_close(tokens[..., 0], expected_x)
    torch.testing.assert_close(tokens[..., 1], expected_y)
    torch.testing.assert_close(tokens[..., 2:], expected_features)


def test_a_peaked_map_finds_the_pixel():
    """A map that is large at one pixel only puts its keypoint there."""
    pool = SpatialSoftmax(1, keypoints=1)
    with torch.no_grad():
        pool.maps.weight.fill_(100.0)
        pool.maps.bias.zero_()
    features = torch.zeros(1, 1, 5, 5)
    features[0, 0, 3, 1] = 1.0  # row 3 (y = 0.5), column 1 (x = -0.5)
    torch.testing.assert_close(pool(features)[0, 0, :2], torch.tensor([-0.5, 0.5]))


def test_the_encoder_shifts_only_in_training_and_downsamples_by_averaging():
    torch.manual_seed(0)
    encoder = ConvEncoder(16, keypoints=4, channels=8, downsample=2, shift=2)
    images = torch.randint(0, 256, (3, 3, 32, 32), dtype=torch.uint8)
    encoder.eval()
    assert torch.equal(encoder(images), encoder(images)), "no augmentation at evaluation"
    encoder.train()
    assert not torch.equal(encoder(images), encoder(images)), "a fresh shift at each training pass"
    encoder.eval()
    low = F.avg_pool2d(images.float(), 2).round().to(torch.uint8)
    plain = ConvEncoder(16, keypoints=4, channels=8, downsample=1, shift=0).eval()
    plain.load_state_dict(encoder.state_dict())
    torch.testing.assert_close(encoder(images), plain(low), atol=0.05, rtol=0)  # up to the rounding to uint8


def test_every_camera_becomes_keypoint_tokens_and_a_missing_one_is_named():
    processor = MiniVLAProcessor(CONFIG, STATS, ["pick up the bowl"])
    assert processor.extra_cameras == ("image2",) and CONFIG.image_tokens == 2 * 4
    frames = np.zeros((2, 32, 32, 3), np.uint8)
    observation = processor.observation(
        np.zeros((2, 2), np.float32), ["pick up the bowl"] * 2, frames, {"image2": frames}
    )
    assert observation["image"].dtype == torch.uint8 and observation["image.image2"].shape == (2, 3, 32, 32)
    context = MiniVLA(CONFIG).encode(observation)
    assert context["mask"].shape == (2, CONFIG.prefix_length) and CONFIG.prefix_length == 4 + 1 + 8
    with pytest.raises(ValueError, match="reads camera 'image2'; no frames were given"):
        processor.observation(np.zeros((2, 2), np.float32), ["pick up the bowl"] * 2, frames)
    with pytest.raises(ValueError, match=r"image.image2 must be uint8 frames of shape \(2, 3, 32, 32\)"):
        MiniVLA(CONFIG).encode({**observation, "image.image2": observation["image.image2"].float()})


def test_the_configuration_round_trips_and_refuses_what_it_cannot_build():
    assert MiniVLAConfig.from_dict(CONFIG.to_dict()) == CONFIG  # the camera names come back from JSON as a list
    with pytest.raises(ValueError, match="patch image encoder reads one camera"):
        dataclasses.replace(CONFIG, image_encoder="patch", patch_size=16)
    with pytest.raises(ValueError, match="image_encoder must be one of"):
        dataclasses.replace(CONFIG, image_encoder="resnet")
    with pytest.raises(ValueError, match="multiple of 8 x image_downsample"):
        dataclasses.replace(CONFIG, image_downsample=3)
    with pytest.raises(ValueError, match=r"conv_width \(12\) must be a multiple of 8"):
        dataclasses.replace(CONFIG, conv_width=12)
    with pytest.raises(ValueError, match="random_shift must be at least 0"):
        dataclasses.replace(CONFIG, random_shift=-1)
    assert "image_encoder" not in MiniVLAConfig().to_dict(), "an option added later is left out at its default"


def _square_scenes(count: int, generator: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Black 32-px frames with one white 6-px square; the target is the square's centre in [-1, 1]."""
    corners = generator.integers(0, 26, size=(count, 2))
    frames = np.zeros((count, 32, 32, 3), np.uint8)
    for frame, (row, column) in zip(frames, corners, strict=True):
        frame[row : row + 6, column : column + 6] = 255
    return frames, ((corners + 3) / 31.5 - 1).astype(np.float32)[:, ::-1].copy()  # (x, y)


@pytest.mark.slow
def test_the_encoder_learns_where_an_object_is_from_pixels_alone():
    """Learning test: the main camera's keypoint tokens, averaged and read by a linear head, give the square's
    position with a small error on scenes never seen in training."""
    torch.manual_seed(0)
    generator = np.random.default_rng(0)
    config = dataclasses.replace(CONFIG, extra_cameras=(), random_shift=0)
    model = MiniVLA(config)
    head = torch.nn.Linear(config.prefix_width, 2)
    processor = MiniVLAProcessor(config, STATS, ["find the square"])
    optimizer = torch.optim.Adam([*model.camera_encoders.parameters(), *head.parameters()], lr=3e-3)
    for _ in range(300):
        frames, targets = _square_scenes(32, generator)
        tokens = model.camera_encoders[0](processor.observation(np.zeros((32, 2)), ["x"] * 32, frames)["image"])
        loss = (head(tokens.mean(1)) - torch.from_numpy(targets)).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    frames, targets = _square_scenes(200, np.random.default_rng(1))
    with torch.no_grad():
        tokens = model.camera_encoders[0](processor.observation(np.zeros((200, 2)), ["x"] * 200, frames)["image"])
        error = (head(tokens.mean(1)) - torch.from_numpy(targets)).pow(2).mean().item()
    assert error < 0.02, f"mean squared error {error:.4f} on held-out scenes (a constant guess gives ~0.33)"
