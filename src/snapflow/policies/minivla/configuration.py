"""Configuration of MiniVLA, the built-in compact vision-language-action policy."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.errors import InvalidInputError
from snapflow.policies.configuration import PolicyConfig
from snapflow.reporting.records import added_option

IMAGE_ENCODERS = ("patch", "conv")
NORM_GROUPS = 8  # GroupNorm groups of the conv encoder: its width must divide into them


@dataclass(frozen=True)
class MiniVLAConfig(PolicyConfig):
    """Sizes of the prefix encoder (instruction, state, optional image) and of the action expert.

    Both share ``num_heads`` x ``head_dim`` attention so that each expert layer can attend to the
    keys and values its prefix layer cached, as pi0's action expert attends to the VLM's.

    The policy reads the leading ``state_dim`` entries of the environment's state vector: 39 is all of
    Meta-World's (hand, gripper, object and goal poses); 4 is proprioception only (hand position and gripper
    opening), which with ``use_image`` leaves the scene to the camera.

    Images (``use_image``): the benchmark's main camera and the ``extra_cameras`` it names (LIBERO's wrist camera,
    ``image2``), each ``image_size`` pixels square, read by one of two ``image_encoder``:

    * ``patch``: ViT patches of ``patch_size``, one token each (the first design; one camera).
    * ``conv``: a small convolutional network a camera (``conv_width`` channels, doubled at each of its three
      stride-2 stages) whose feature map is pooled by a spatial softmax into ``keypoints`` tokens, each the expected
      position of a learned map's peak and the features there, as robomimic and Diffusion Policy pool theirs;
      ``image_downsample`` averages pixels first (2: a 128-px camera read at 64 px); in training each frame is
      shifted by up to ``random_shift`` pixels (DrQ's random shift: pad by repeating the border, crop back).
    """

    state_dim: int = 39
    action_dim: int = 4
    chunk_length: int = 8
    vocab_size: int = 512
    max_instruction_tokens: int = 12
    use_image: bool = False
    image_size: int = 64
    patch_size: int = 16
    prefix_width: int = 192
    expert_width: int = 128
    num_layers: int = 3
    num_heads: int = 4
    head_dim: int = 32
    mlp_ratio: int = 4
    image_encoder: str = added_option("patch")
    extra_cameras: tuple[str, ...] = added_option(())
    keypoints: int = added_option(32)
    conv_width: int = added_option(32)
    image_downsample: int = added_option(1)
    random_shift: int = added_option(0, metadata={"minimum": 0})

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.image_encoder not in IMAGE_ENCODERS:
            raise InvalidInputError(
                f"MiniVLAConfig.image_encoder must be one of {IMAGE_ENCODERS}, got {self.image_encoder!r}"
            )
        if not self.use_image:
            return
        if self.image_encoder == "patch":
            if self.image_size % self.patch_size:
                raise InvalidInputError(
                    f"MiniVLAConfig.image_size ({self.image_size}) must be a multiple of patch_size ({self.patch_size})"
                )
            if self.extra_cameras:
                raise InvalidInputError(
                    "MiniVLAConfig: the patch image encoder reads one camera; use image_encoder='conv'"
                )
        elif self.image_size % (8 * self.image_downsample):
            raise InvalidInputError(
                f"MiniVLAConfig.image_size ({self.image_size}) must be a multiple of 8 x image_downsample "
                f"({8 * self.image_downsample}): the conv encoder halves it three times"
            )
        elif self.conv_width % NORM_GROUPS:
            raise InvalidInputError(
                f"MiniVLAConfig.conv_width ({self.conv_width}) must be a multiple of {NORM_GROUPS}: the conv encoder "
                f"normalises its channels in {NORM_GROUPS} groups"
            )

    @property
    def cameras(self) -> int:
        """How many cameras the policy reads (0 without images)."""
        return 1 + len(self.extra_cameras) if self.use_image else 0

    @property
    def tokens_per_camera(self) -> int:
        if self.image_encoder == "conv":
            return self.keypoints
        return (self.image_size // self.patch_size) ** 2

    @property
    def image_tokens(self) -> int:
        """Image tokens in the prefix, all cameras'."""
        return self.cameras * self.tokens_per_camera

    @property
    def prefix_length(self) -> int:
        return self.max_instruction_tokens + 1 + self.image_tokens
