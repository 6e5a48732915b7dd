"""Frames kept as video by LeRobot's encoder: its settings for the LeRobot installed, the check that every frame was
encoded, and the frames decoded back in order."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.adapters.lerobot_config import VIDEO_CODECS, VideoEncoding
from snapflow.errors import InvalidInputError

# LeRobot's streaming encoder drops a frame whose queue stays full for 0.1 s (it was made for recording a robot in
# real time: one frame of an episode was lost on loaded cores); a queue longer than any episode never fills
ENCODER_QUEUE = 100_000


def encoder_options(encoding: VideoEncoding) -> dict[str, Any]:
    """``LeRobotDataset.create``'s arguments that encode the frames with ``encoding``, as they are added (no PNG
    written and read back a frame: a 64-px LIBERO episode of two cameras in ~1 s instead of ~4 s on shared cores)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if encoding.codec not in VIDEO_CODECS:
        raise InvalidInputError(f"video codec must be one of {list(VIDEO_CODECS)}, got {encoding.codec!r}")
    if "rgb_encoder" not in inspect.signature(LeRobotDataset.create).parameters:
        raise InvalidInputError(
            "frames as video with a chosen key-frame distance, quality and preset need LeRobot >= 0.5 (Python 3.12); "
            "this LeRobot encodes with its own"
        )
    from lerobot.configs.video import RGBEncoderConfig

    encoder = RGBEncoderConfig(vcodec=encoding.codec, g=encoding.gop, crf=encoding.crf, preset=encoding.preset)
    return {"rgb_encoder": encoder, "streaming_encoding": True, "encoder_queue_maxsize": ENCODER_QUEUE}


def decoded_frames(root: str | Path, feature: str) -> np.ndarray:
    """Every frame of the video feature ``feature`` of the LeRobotDataset at ``root``, decoded in the dataset's order
    (its video files in order, each from its first frame), (N, H, W, 3) uint8."""
    import av  # PyAV, LeRobot's video backend

    frames = []
    for path in sorted((Path(root) / "videos" / feature).rglob("*.mp4")):
        with av.open(str(path)) as container:
            frames += [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    return np.stack(frames)


def check_video_lengths(root: str | Path, fps: int) -> None:
    """Raise where a video of the dataset at ``root`` holds another number of frames for an episode than the episode
    has: a frame the encoder lost would shift every later frame of its file against its state and action."""
    import pandas as pd

    episodes = pd.concat(
        pd.read_parquet(path) for path in sorted((Path(root) / "meta" / "episodes").rglob("*.parquet"))
    )
    for column in (name for name in episodes.columns if name.endswith("/from_timestamp")):
        feature = column.removeprefix("videos/").removesuffix("/from_timestamp")
        span = episodes[f"videos/{feature}/to_timestamp"] - episodes[column]
        lost = [
            int(index)
            for index, (seconds, length) in enumerate(zip(span, episodes["length"], strict=True))
            if round(seconds * fps) != length
        ]
        if lost:
            raise RuntimeError(f"{root}: the {feature} video lost frames of episodes {lost}; the dataset is unusable")


def frame_error(decoded: np.ndarray, rendered: np.ndarray) -> dict[str, float | None]:
    """How far decoded frames are from the rendered ones: mean and largest absolute error (of 255) and PSNR (dB; None
    where they are equal)."""
    difference = decoded.astype(np.float64) - rendered
    mse = float(np.mean(difference**2))
    return {
        "mean_abs_error": float(np.mean(np.abs(difference))),
        "max_abs_error": float(np.max(np.abs(difference))),
        "psnr_db": float(10 * np.log10(255.0**2 / mse)) if mse else None,
    }


__all__ = ["ENCODER_QUEUE", "encoder_options", "decoded_frames", "check_video_lengths", "frame_error"]
