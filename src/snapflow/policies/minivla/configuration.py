"""Configuration of MiniVLA, the built-in compact vision-language-action policy."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.policies.configuration import PolicyConfig


@dataclass(frozen=True)
class MiniVLAConfig(PolicyConfig):
    """Sizes of the prefix encoder (instruction, state, optional image) and of the action expert.

    Both share ``num_heads`` x ``head_dim`` attention so that each expert layer can attend to the
    keys and values its prefix layer cached, as pi0's action expert attends to the VLM's.

    The policy reads the leading ``state_dim`` entries of the environment's state vector: 39 is all of
    Meta-World's (hand, gripper, object and goal poses); 4 is proprioception only (hand position and gripper
    opening), which with ``use_image`` leaves the scene to the camera.
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

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.use_image and self.image_size % self.patch_size:
            raise ValueError(
                f"MiniVLAConfig.image_size ({self.image_size}) must be a multiple of patch_size ({self.patch_size})"
            )

    @property
    def num_patches(self) -> int:
        return (self.image_size // self.patch_size) ** 2 if self.use_image else 0

    @property
    def prefix_length(self) -> int:
        return self.max_instruction_tokens + 1 + self.num_patches
