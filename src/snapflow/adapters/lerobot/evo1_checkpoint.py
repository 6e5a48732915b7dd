"""A random InternVL3 written locally, offline, for LeRobot's EVO1: its config, random weights and a word-level
tokenizer with InternVL's image tokens (``<img>``, ``</img>``, ``<IMG_CONTEXT>``). EVO1's embedder loads the VLM by
``AutoModel.from_pretrained(vlm_model_name)``, so the folder holds weights, unlike a SmolVLM's. At full size
(InternVL3-1B's InternViT-300M and Qwen2.5-0.5B, cut to the 14 language layers EVO1 keeps, in bfloat16: about 1.3 GB)
``snapflow bench --architecture evo1 --vlm FOLDER`` times EVO1 with random weights; the tests build a tiny one.

Run as a module::

    python -m snapflow.adapters.lerobot.evo1_checkpoint FOLDER [--size full]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: InternVL's image tokens, as EVO1's embedder writes them into its prompt
IMAGE_TOKENS = ["<img>", "</img>", "<IMG_CONTEXT>"]
#: EVO1's prompt heads each view with "Image-<n>:", which the word-level tokenizer splits at punctuation
WORDS = "image - 1 2 3 : pick place push open close the a to red blue cube drawer goal robot".split()


@dataclass(frozen=True)
class InternVLSize:
    """An InternVL3's vision tower (InternViT) and language model (Qwen2), and the dtype its weights are saved in."""

    vision: dict[str, Any]
    text: dict[str, Any]
    #: the vocabulary's rows (None: the word-level tokenizer's own size)
    vocab_size: int | None
    weights_dtype: str = "bfloat16"


SIZES = {
    # InternVL3-1B: InternViT-300M at 448 pixels (256 image tokens) and Qwen2.5-0.5B, cut to EVO1's 14 layers
    "full": InternVLSize(
        vision=dict(
            hidden_size=1024, num_hidden_layers=24, num_attention_heads=16, intermediate_size=4096, image_size=448
        ),
        text=dict(
            hidden_size=896,
            intermediate_size=4864,
            num_hidden_layers=14,
            num_attention_heads=14,
            num_key_value_heads=2,
            max_position_embeddings=32768,
            rope_theta=1e6,
        ),
        vocab_size=151674,
    ),
    # the tests': a one-layer vision tower at 28 pixels (4 patches, one image token), two language layers of 32
    "tiny": InternVLSize(
        vision=dict(hidden_size=16, num_hidden_layers=1, num_attention_heads=2, intermediate_size=32, image_size=28),
        text=dict(
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
            num_key_value_heads=1,
            max_position_embeddings=512,
        ),
        vocab_size=None,
        weights_dtype="float32",
    ),
}


def write_random_internvl3(directory: str | Path, size: str = "full", seed: int = 0) -> Path:
    """A random InternVL3 at ``size`` (config, weights from ``seed``, tokenizer) in ``directory``, named by its
    absolute path (EVO1's ``vlm_model_name``: LeRobot reads a relative one as a hub id)."""
    import torch
    from transformers import InternVLConfig, InternVLModel

    from snapflow.adapters.lerobot.smolvlm import word_level_tokenizer

    directory, chosen = Path(directory).resolve(), SIZES[size]
    tokenizer = word_level_tokenizer(
        [*IMAGE_TOKENS, *WORDS],
        additional_special_tokens=IMAGE_TOKENS,
        model_max_length=4096,
        padding_side="right",  # EVO1 pools its right-padded causal decoder's last real token
    )
    tokenizer.save_pretrained(directory)
    vision = chosen.vision
    tokens = (vision["image_size"] // 14) ** 2 // 4  # 14-pixel patches, downsampled by 2 each way
    config = InternVLConfig(
        vision_config=dict(**vision, patch_size=14),
        text_config=dict(
            model_type="qwen2",
            vocab_size=chosen.vocab_size or len(tokenizer),
            **chosen.text,
            tie_word_embeddings=True,
            pad_token_id=tokenizer.pad_token_id,
        ),
        image_token_id=tokenizer.convert_tokens_to_ids("<IMG_CONTEXT>"),
        image_seq_length=tokens,
        downsample_ratio=0.5,
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = InternVLModel(config).to(getattr(torch, chosen.weights_dtype))
    model.save_pretrained(directory)
    return directory


def main(arguments: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where the InternVL3 folder goes")
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    options = parser.parse_args(arguments)
    print(write_random_internvl3(options.directory, options.size))


if __name__ == "__main__":
    main()


__all__ = ["IMAGE_TOKENS", "InternVLSize", "SIZES", "write_random_internvl3"]
