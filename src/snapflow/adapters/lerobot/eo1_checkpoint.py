"""A random Qwen2.5-VL written locally, offline, for LeRobot's EO-1: its config, random weights, a word-level tokenizer
with Qwen's chat tokens and EO-1's own, Qwen's chat template and image processor. EO-1 loads its backbone by
``Qwen2_5_VLForConditionalGeneration.from_pretrained(vlm_base)`` and its pre-processor by
``Qwen2_5_VLProcessor.from_pretrained(vlm_base)``, so the folder holds weights and a processor. At full size
(Qwen2.5-VL-3B-Instruct's dimensions, in bfloat16: about 7.5 GB) ``snapflow bench --architecture eo1 --vlm FOLDER``
times EO-1 with random weights; the tests build a tiny one.

Run as a module::

    python -m snapflow.adapters.lerobot.eo1_checkpoint FOLDER [--size full]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: the special tokens of Qwen2.5-VL's chat template and of its image placeholders
QWEN_TOKENS = ["<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>", "<|image_pad|>", "<|video_pad|>"]
#: EO-1's own (LeRobot's ``EO1_SPECIAL_TOKENS``): in the vocabulary already, so its processor step adds none and every
#: id has an embedding row
EO1_TOKENS = [
    "<|action_start|>",
    "<|action_pad|>",
    "<|action_end|>",
    "<|state_start|>",
    "<|state_pad|>",
    "<|state_end|>",
    "<|vla|>",
]
#: EO-1's system message and the tasks' words, which the word-level tokenizer splits at punctuation
WORDS = "system user assistant you are a helpful physical . pick place push open close the to red blue cube drawer"
#: Qwen2-VL's chat template (images as ``<|vision_start|><|image_pad|><|vision_end|>``), as its processor applies it
CHAT_TEMPLATE = (
    "{% for message in messages %}{% if loop.first and message['role'] != 'system' %}<|im_start|>system\n"
    "You are a helpful assistant.<|im_end|>\n{% endif %}<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}<|im_end|>\n{% else %}"
    "{% for content in message['content'] %}{% if content['type'] == 'image' or 'image' in content %}"
    "<|vision_start|><|image_pad|><|vision_end|>{% elif 'text' in content %}{{ content['text'] }}{% endif %}"
    "{% endfor %}<|im_end|>\n{% endif %}{% endfor %}{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)


@dataclass(frozen=True)
class QwenVLSize:
    """A Qwen2.5-VL's vision tower and language model, its image processor's pixel range and its weights' dtype."""

    vision: dict[str, Any]
    text: dict[str, Any]
    #: the vocabulary's rows (None: the word-level tokenizer's own size)
    vocab_size: int | None
    #: the image processor's (min, max) pixels: EO-1's ``image_min_pixels`` / ``image_max_pixels``
    pixels: tuple[int, int]
    weights_dtype: str = "bfloat16"


SIZES = {
    # Qwen2.5-VL-3B-Instruct: a 32-block ViT of 1280 (full attention every 8th block) and a 36-layer Qwen2.5 of 2048
    "full": QwenVLSize(
        vision=dict(
            depth=32,
            hidden_size=1280,
            intermediate_size=3420,
            num_heads=16,
            out_hidden_size=2048,
            window_size=112,
            fullatt_block_indexes=[7, 15, 23, 31],
            tokens_per_second=2,
        ),
        text=dict(
            hidden_size=2048,
            intermediate_size=11008,
            num_hidden_layers=36,
            num_attention_heads=16,
            num_key_value_heads=2,
            max_position_embeddings=128000,
            rms_norm_eps=1e-6,
            rope_parameters={"rope_type": "default", "mrope_section": [16, 24, 24], "rope_theta": 1e6},
        ),
        vocab_size=151936,
        pixels=(64 * 28 * 28, 128 * 28 * 28),
    ),
    # the tests': one vision block of 16, two language layers of 32; a 56-pixel image is 16 patches, 4 image tokens
    "tiny": QwenVLSize(
        vision=dict(
            depth=1, hidden_size=16, intermediate_size=32, num_heads=2, out_hidden_size=32, fullatt_block_indexes=[0]
        ),
        text=dict(
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
            num_key_value_heads=1,
            max_position_embeddings=512,
            rope_parameters={"rope_type": "default", "mrope_section": [2, 3, 3], "rope_theta": 1e6},
        ),
        vocab_size=None,
        pixels=(56 * 56, 56 * 56),
        weights_dtype="float32",
    ),
}


def qwen_vl_config(size: str, tokenizer: Any) -> Any:
    """The ``Qwen2_5_VLConfig`` of ``size`` whose special token ids are ``tokenizer``'s."""
    from transformers import Qwen2_5_VLConfig

    chosen, ids = SIZES[size], tokenizer.convert_tokens_to_ids
    return Qwen2_5_VLConfig(
        vision_config=chosen.vision,
        text_config=dict(
            vocab_size=chosen.vocab_size or len(tokenizer),
            **chosen.text,
            pad_token_id=tokenizer.pad_token_id,
            bos_token_id=None,
            eos_token_id=ids("<|im_end|>"),
        ),
        image_token_id=ids("<|image_pad|>"),
        video_token_id=ids("<|video_pad|>"),
        vision_start_token_id=ids("<|vision_start|>"),
        vision_end_token_id=ids("<|vision_end|>"),
        tie_word_embeddings=True,  # as Qwen2.5-VL-3B ties its output head to its embedding
        dtype=chosen.weights_dtype,
    )


def qwen_vl_processor(size: str) -> Any:
    """A ``Qwen2_5_VLProcessor`` over a word-level tokenizer (Qwen's and EO-1's special tokens, :data:`WORDS`) and
    Qwen2-VL's image processor, resizing to ``size``'s pixel range."""
    from transformers import Qwen2_5_VLProcessor
    from transformers.models.qwen2_vl.image_processing_pil_qwen2_vl import Qwen2VLImageProcessorPil
    from transformers.models.qwen2_vl.video_processing_qwen2_vl import Qwen2VLVideoProcessor

    from snapflow.adapters.lerobot.smolvlm import word_level_tokenizer

    tokenizer = word_level_tokenizer(
        [*QWEN_TOKENS, *EO1_TOKENS, *WORDS.split()],
        additional_special_tokens=[*QWEN_TOKENS, *EO1_TOKENS],
        eos_token="<|im_end|>",
        model_max_length=32768,
        padding_side="right",
    )
    low, high = SIZES[size].pixels
    return Qwen2_5_VLProcessor(
        image_processor=Qwen2VLImageProcessorPil(min_pixels=low, max_pixels=high),
        tokenizer=tokenizer,
        video_processor=Qwen2VLVideoProcessor(),
        chat_template=CHAT_TEMPLATE,
    )


def write_random_qwen2_5_vl(directory: str | Path, size: str = "full", seed: int = 0) -> Path:
    """A random Qwen2.5-VL at ``size`` (config, weights from ``seed``, processor) in ``directory``, named by its
    absolute path (EO-1's ``vlm_base``, which a policy's saved config and processor keep as given: a relative one
    opens only from the working directory it was written in)."""
    import torch
    from transformers import Qwen2_5_VLForConditionalGeneration

    directory = Path(directory).resolve()
    processor = qwen_vl_processor(size)
    processor.save_pretrained(directory)
    config = qwen_vl_config(size, processor.tokenizer)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        # built in its saved dtype: a full-size one never holds a float32 copy (15 GB)
        model = Qwen2_5_VLForConditionalGeneration._from_config(config, dtype=getattr(torch, SIZES[size].weights_dtype))
    model.save_pretrained(directory)
    return directory


def parameter_count(size: str = "full") -> int:
    """The parameters of a Qwen2.5-VL of ``size``, built on the meta device (no memory, no weights)."""
    import torch
    from transformers import Qwen2_5_VLForConditionalGeneration

    config = qwen_vl_config(size, qwen_vl_processor(size).tokenizer)
    with torch.device("meta"):
        model = Qwen2_5_VLForConditionalGeneration._from_config(config)
    return sum(parameter.numel() for parameter in model.parameters())  # the tied output head counted once


def main(arguments: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where the Qwen2.5-VL folder goes")
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    options = parser.parse_args(arguments)
    print(write_random_qwen2_5_vl(options.directory, options.size))


if __name__ == "__main__":
    main()


__all__ = ["EO1_TOKENS", "QWEN_TOKENS", "QwenVLSize", "SIZES", "parameter_count", "write_random_qwen2_5_vl"]
