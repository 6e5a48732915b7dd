"""A SmolVLA of a size chosen here, built offline: LeRobot's own ``SmolVLAPolicy`` over a SmolVLM whose config,
word-level tokenizer and processor are written to a local folder (no hub access, no pretrained weights).

LeRobot builds SmolVLA's VLM from ``config.vlm_model_name``: with ``load_vlm_weights=False`` it reads only the
config and the processor there, so a folder written by :func:`write_smolvlm` stands in for the hub's
``HuggingFaceTB/SmolVLM2-500M-Video-Instruct``. Used to train SmolVLA teachers from scratch on a CPU and by the tests.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import SmolVLMSize

IMAGE_TOKENS = {
    "fake_image_token": "<fake_token_around_image>",
    "image_token": "<image>",
    "global_image_token": "<global-img>",
    "end_of_utterance_token": "<end_of_utterance>",
}
OTHER_SPECIAL_TOKENS = ["<|im_start|>", "<|endoftext|>", "<video>"]
ROW_COL_TOKENS = [f"<row_{i}_col_{j}>" for i in range(1, 5) for j in range(1, 5)]


def _tokens(text: str) -> list[str]:
    return re.findall(r"\w+|[^\w\s]", text.lower())  # what the word-level tokenizer splits


def words_of(texts: Iterable[str]) -> list[str]:
    """The lower-cased words and punctuation marks of ``texts``, in order of first use: the tokenizer's vocabulary."""
    return list(dict.fromkeys(token for text in texts for token in _tokens(text)))


def token_budget(texts: Iterable[str]) -> int:
    """Tokens to pad instructions to: the longest one's and one more, in multiples of 8 (SmolVLA's default of 48
    would make a short instruction's prefix mostly padding, and every training step pay for it)."""
    return 8 * math.ceil((max(len(_tokens(text)) for text in texts) + 1) / 8)


def word_level_tokenizer(tokens: Iterable[str], **options: Any) -> Any:
    """A tokenizer whose vocabulary is ``[PAD]``, ``[UNK]`` and ``tokens``, splitting lower-cased text at whitespace
    into whole words (a local VLM's for tiny and from-scratch policies: no subword model to download); ``options``
    are :class:`transformers.PreTrainedTokenizerFast`'s (special tokens, padding side)."""
    from tokenizers import Tokenizer, normalizers, pre_tokenizers
    from tokenizers.models import WordLevel
    from transformers import PreTrainedTokenizerFast

    vocabulary: dict[str, int] = {}
    for token in ["[PAD]", "[UNK]", *tokens]:
        vocabulary.setdefault(token, len(vocabulary))
    core = Tokenizer(WordLevel(vocab=vocabulary, unk_token="[UNK]"))
    core.normalizer = normalizers.Lowercase()
    core.pre_tokenizer = pre_tokenizers.Whitespace()
    return PreTrainedTokenizerFast(tokenizer_object=core, pad_token="[PAD]", unk_token="[UNK]", **options)


def write_smolvlm(directory: str | Path, words: Iterable[str], size: SmolVLMSize) -> Path:
    """A SmolVLM config, processor and word-level tokenizer of ``words`` in ``directory`` (what LeRobot's
    SmolVLA and its tokenizer step read from ``vlm_model_name``)."""
    from transformers import SmolVLMConfig, SmolVLMImageProcessor, SmolVLMProcessor
    from transformers.models.smolvlm.video_processing_smolvlm import SmolVLMVideoProcessor

    tokenizer = word_level_tokenizer(
        [*OTHER_SPECIAL_TOKENS, *IMAGE_TOKENS.values(), *ROW_COL_TOKENS, *words],
        bos_token="<|im_start|>",
        eos_token="<end_of_utterance>",
        additional_special_tokens=[*OTHER_SPECIAL_TOKENS[2:], *IMAGE_TOKENS.values(), *ROW_COL_TOKENS],
        extra_special_tokens=dict(IMAGE_TOKENS),
        model_max_length=512,
        padding_side="right",
    )
    edge = {"longest_edge": size.image_size}
    SmolVLMProcessor(
        image_processor=SmolVLMImageProcessor(
            do_resize=True, size=edge, do_image_splitting=False, max_image_size=edge, do_pad=True
        ),
        tokenizer=tokenizer,
        video_processor=SmolVLMVideoProcessor(size=edge, max_image_size=edge, do_image_splitting=False),
        image_seq_len=size.image_tokens,
    ).save_pretrained(directory)
    SmolVLMConfig(
        vision_config=dict(
            hidden_size=size.vision_hidden,
            intermediate_size=size.vision_intermediate or 2 * size.vision_hidden,
            num_hidden_layers=size.vision_layers,
            num_attention_heads=size.vision_heads,
            image_size=size.image_size,
            patch_size=size.patch_size,
        ),
        text_config=dict(
            model_type="llama",
            hidden_size=size.text_hidden,
            intermediate_size=size.text_intermediate or 2 * size.text_hidden,
            num_hidden_layers=size.text_layers,
            num_attention_heads=size.text_heads,
            num_key_value_heads=size.text_kv_heads,
            head_dim=size.text_hidden // size.text_heads,
            vocab_size=len(tokenizer),
            max_position_embeddings=size.max_positions,
            pad_token_id=tokenizer.pad_token_id,
            tie_word_embeddings=False,
        ),
        scale_factor=size.scale_factor,
        image_token_id=tokenizer.convert_tokens_to_ids("<image>"),
        pad_token_id=tokenizer.pad_token_id,
    ).save_pretrained(directory)
    return Path(directory)


def feature_widths(input_features: dict[str, Any], output_features: dict[str, Any]) -> tuple[int, int]:
    """(state width, action width) of LeRobot policy features: what a policy trained from scratch pads its state and
    action to, and no more."""
    state = next(feature for feature in input_features.values() if feature.type.name == "STATE")
    return state.shape[0], next(iter(output_features.values())).shape[0]


def smolvla_config(
    vlm_directory: str | Path,
    input_features: dict[str, Any],
    output_features: dict[str, Any],
    size: SmolVLMSize,
    **overrides: Any,
) -> Any:
    """LeRobot's ``SmolVLAConfig`` over the SmolVLM in ``vlm_directory``, randomly initialised, with state and action
    padded to no more than the features' own widths, every part trainable, on the CPU; ``overrides`` win."""
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig

    state_width, action_width = feature_widths(input_features, output_features)
    settings: dict[str, Any] = dict(
        vlm_model_name=str(vlm_directory),
        load_vlm_weights=False,
        num_vlm_layers=size.text_layers,
        expert_width_multiplier=0.5,
        resize_imgs_with_padding=(size.image_size, size.image_size),
        max_state_dim=state_width,
        max_action_dim=action_width,
        freeze_vision_encoder=False,
        train_expert_only=False,
        device="cpu",
        push_to_hub=False,
        input_features=input_features,
        output_features=output_features,
    )
    return SmolVLAConfig(**{**settings, **overrides})


__all__ = ["token_budget", "words_of", "word_level_tokenizer", "write_smolvlm", "feature_widths", "smolvla_config"]
