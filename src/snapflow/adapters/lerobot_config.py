"""Settings of the LeRobot teachers snapflow trains, in plain Python: the CLI reads them before LeRobot (or torch)
is imported, and without LeRobot installed."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class SmolVLMSize:
    """The SmolVLM's dimensions (SmolVLA's action expert is ``expert_width_multiplier`` times the text width)."""

    image_size: int = 64
    patch_size: int = 16
    scale_factor: int = 2  # pixel shuffle: (image_size / patch_size)^2 / scale_factor^2 image tokens
    vision_hidden: int = 32
    vision_layers: int = 1
    vision_heads: int = 2
    text_hidden: int = 64
    text_layers: int = 2
    text_heads: int = 4
    text_kv_heads: int = 2
    max_positions: int = 256
    vision_intermediate: int | None = None  # the MLP widths; None: twice the hidden width
    text_intermediate: int | None = None

    @property
    def image_tokens(self) -> int:
        return (self.image_size // self.patch_size) ** 2 // self.scale_factor**2


SMOLVLM_SIZES = {
    "tiny": SmolVLMSize(),  # ~0.2M parameters: the tests' size
    # a few million parameters, the size of the demo's built-in policy: trains to a Meta-World teacher on a CPU
    "small": SmolVLMSize(
        vision_hidden=64, vision_layers=2, text_hidden=192, text_layers=4, text_heads=6, text_kv_heads=2
    ),
    # 11.6M parameters over LIBERO's words (small: 2.0M): twice small's widths, two more layers in each tower; the
    # candidate for forty LIBERO tasks, where small may lack the capacity (smolvla-libero-four-suites.toml compares them)
    "medium": SmolVLMSize(
        vision_hidden=128,
        vision_layers=4,
        vision_heads=4,
        text_hidden=384,
        text_layers=6,
        text_heads=6,
        text_kv_heads=2,
    ),
    # SmolVLA's own, HuggingFaceTB/SmolVLM2-500M-Video-Instruct's dimensions (a SigLIP at 512 px, SmolLM2's 32 text
    # layers of which SmolVLA keeps 16), with the word-level vocabulary written here: for timing at full size
    "full": SmolVLMSize(
        image_size=512,
        scale_factor=4,
        vision_hidden=768,
        vision_intermediate=3072,
        vision_layers=12,
        vision_heads=12,
        text_hidden=960,
        text_intermediate=2560,
        text_layers=32,
        text_heads=15,
        text_kv_heads=5,
        max_positions=8192,
    ),
}


#: the video codecs a sweep may store its frames with (LeRobot's encoder names; AV1 is LeRobot's default and its
#: smallest)
VIDEO_CODECS = ("libsvtav1", "h264", "hevc")


@dataclass(frozen=True)
class VideoEncoding:
    """How LeRobot's encoder keeps a sweep's frames as video (``[data] video``): the codec, the distance between key
    frames (``gop``), the quality (``crf``: higher, smaller and coarser) and the encoder's speed (``preset``: lower,
    slower and smaller). The defaults were chosen on 1,830 frames of LIBERO-Spatial task 1 (64 px, both cameras):
    LeRobot's own (a key frame every 2 frames, preset 12) took 622 bytes a frame at PSNR 35.9 / 33.7 dB
    (agentview / wrist); these take 192 bytes at 38.4 / 34.8 dB, ~1 s an episode to encode. Frequent key frames make
    decoding one frame at random cheap, which training does not need here: the runs read PNG frames decoded once from
    the video (a frame from video took 8.3 ms, from PNG 1.5 ms)."""

    codec: str = "libsvtav1"
    gop: int = 128
    crf: int = 30
    preset: int = 4


# the decoder of a dataset's video frames in snapflow's training and in the lerobot-train it runs: PyAV brings its own
# FFmpeg; torchcodec (LeRobot's first choice) needs the system's, and without it LeRobot falls back to PyAV only after
# a traceback of a hundred lines in every process
VIDEO_BACKEND = "pyav"


@dataclass(frozen=True)
class LeRobotSpec:
    """A LeRobot policy trained from scratch on a sweep's demonstrations, written as a LeRobotDataset: ``snapflow
    train --policy-type <policy_type>``'s settings (SmolVLA over a SmolVLM of size ``smolvlm``, X-VLA over a Florence-2
    at that size's widths, reading the frames at ``image_size``, None: that size's own)."""

    policy_type: str = "smolvla"
    smolvlm: str = "small"
    image_size: int | None = None
    chunk_size: int = 8
    n_action_steps: int = 4

    @property
    def size(self) -> SmolVLMSize:
        """The VLM's widths, reading the frames at :attr:`image_size` where given."""
        size = SMOLVLM_SIZES[self.smolvlm]
        return size if self.image_size is None else replace(size, image_size=self.image_size)


__all__ = ["LeRobotSpec", "SmolVLMSize", "SMOLVLM_SIZES", "VIDEO_CODECS", "VideoEncoding", "VIDEO_BACKEND"]
