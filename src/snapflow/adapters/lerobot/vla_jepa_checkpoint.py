"""A random Qwen3-VL (and, for the world model, a random V-JEPA 2) written locally, offline, with weights, for
LeRobot's VLA-JEPA. Its ``Qwen3VLInterface`` loads the VLM by ``Qwen3VLForConditionalGeneration.from_pretrained(
qwen_model_name)`` and, where ``enable_world_model``, the video encoder by ``AutoModel.from_pretrained(
jepa_encoder_name)``: both folders hold weights, unlike GR00T's Qwen3-VL folder, whose config and processor files
(:func:`~snapflow.adapters.lerobot.groot_checkpoint.write_qwen3_vl`: a word-level tokenizer with Qwen's special
tokens and chat template, image and video processors) are written the same way here.

At full size (Qwen3-VL-2B-Instruct, 2.13B parameters, in bfloat16: about 4.3 GB) ``snapflow bench --architecture
vla_jepa --vlm FOLDER/qwen3_vl`` times VLA-JEPA with random weights; the tests build a tiny one, with a tiny V-JEPA 2.

Run as a module::

    python -m snapflow.adapters.lerobot.vla_jepa_checkpoint FOLDER [--size full] [--world-model]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

QWEN_FOLDER, VJEPA_FOLDER = "qwen3_vl", "vjepa2"


@dataclass(frozen=True)
class VLAJEPABackbones:
    """The Qwen3-VL (a GR00T-checkpoint size: its text and vision towers, processor pixels) and the V-JEPA 2 video
    encoder (its ``VJEPA2Config`` fields and its video processor's frame size) a VLA-JEPA loads."""

    qwen: str
    vjepa: dict[str, Any]
    frame_size: int
    weights_dtype: str = "bfloat16"


SIZES = {
    # Qwen3-VL-2B-Instruct (GR00T N1.7's Cosmos-Reason2-2B has its dimensions) and V-JEPA 2 ViT-L at 256 pixels:
    # LeRobot's VLA-JEPA defaults, Qwen/Qwen3-VL-2B-Instruct and facebook/vjepa2-vitl-fpc64-256
    "full": VLAJEPABackbones(qwen="full", vjepa={}, frame_size=256),
    # the tests': the tiny GR00T's two-layer Qwen3-VL, and a one-layer V-JEPA 2 at 32 pixels (a 2 x 2 patch grid);
    # 24 wide over 2 heads, so the world model's predictor's rotary split keeps 4 channels a axis
    "tiny": VLAJEPABackbones(
        qwen="tiny",
        vjepa=dict(
            crop_size=32,
            frames_per_clip=4,
            hidden_size=24,
            num_attention_heads=2,
            num_hidden_layers=1,
            pred_hidden_size=16,
            pred_num_attention_heads=2,
            pred_num_hidden_layers=1,
        ),
        frame_size=32,
        weights_dtype="float32",
    ),
}


def write_random_qwen3_vl(directory: Path, size: VLAJEPABackbones, seed: int = 0) -> Path:
    """A random Qwen3-VL at ``size``: GR00T's checkpoint writer's config and processor files, and weights."""
    import torch
    from transformers import Qwen3VLConfig, Qwen3VLForConditionalGeneration

    from snapflow.adapters.lerobot.groot_checkpoint import SIZES as QWEN_SIZES
    from snapflow.adapters.lerobot.groot_checkpoint import write_qwen3_vl

    write_qwen3_vl(directory, QWEN_SIZES[size.qwen])
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        # built in its saved dtype: a full-size one in float32 first would take 8.5 GB
        config, dtype = Qwen3VLConfig.from_pretrained(directory), getattr(torch, size.weights_dtype)
        Qwen3VLForConditionalGeneration._from_config(config, dtype=dtype).save_pretrained(directory)
    return directory


def write_random_vjepa2(directory: Path, size: VLAJEPABackbones, seed: int = 0) -> Path:
    """A random V-JEPA 2 at ``size`` (its encoder and its own predictor, as ``AutoModel`` builds it) and its video
    processor."""
    import torch
    from transformers import VJEPA2Config, VJEPA2Model
    from transformers.models.vjepa2.video_processing_vjepa2 import VJEPA2VideoProcessor

    frame = size.frame_size
    VJEPA2VideoProcessor(crop_size={"height": frame, "width": frame}, size={"shortest_edge": frame}).save_pretrained(
        directory
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        VJEPA2Model._from_config(VJEPA2Config(**size.vjepa), dtype=getattr(torch, size.weights_dtype)).save_pretrained(
            directory
        )
    return directory


def write_random_vla_jepa(directory: str | Path, size: str = "full", world_model: bool = False) -> tuple[Path, ...]:
    """The Qwen3-VL folder (VLA-JEPA's ``qwen_model_name``) inside ``directory``, and with ``world_model`` the V-JEPA 2
    folder (its ``jepa_encoder_name``) beside it: named by absolute paths (LeRobot reads a relative one as a hub id)."""
    directory, chosen = Path(directory).resolve(), SIZES[size]
    qwen = write_random_qwen3_vl(directory / QWEN_FOLDER, chosen)
    return (qwen, write_random_vjepa2(directory / VJEPA_FOLDER, chosen)) if world_model else (qwen,)


def main(arguments: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where the Qwen3-VL (and V-JEPA 2) folders go")
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    parser.add_argument(
        "--world-model",
        action="store_true",
        help="also write a random V-JEPA 2, which a VLA-JEPA with enable_world_model (its default) loads; timing "
        "needs none: the world model is a training-time loss that sampling never runs",
    )
    options = parser.parse_args(arguments)
    print(*write_random_vla_jepa(options.directory, options.size, options.world_model), sep="\n")


if __name__ == "__main__":
    main()


__all__ = [
    "SIZES",
    "VLAJEPABackbones",
    "write_random_qwen3_vl",
    "write_random_vjepa2",
    "write_random_vla_jepa",
]
