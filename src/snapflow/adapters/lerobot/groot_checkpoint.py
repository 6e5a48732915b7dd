"""A random GR00T N1.7 checkpoint written locally, offline: a Qwen3-VL folder (its config, a word-level tokenizer
with Qwen's special tokens and chat template, its image and video processors; no weights) and a GR00T N1.7
checkpoint over it with the processor sidecars LeRobot's ``GrootPolicy`` reads. At full size (GR00T N1.7's own
defaults over Cosmos-Reason2-2B's Qwen3-VL dimensions) ``snapflow bench --architecture groot --vlm FOLDER`` times it
with random weights; the tests build a tiny one.

Run as a module::

    python -m snapflow.adapters.lerobot.groot_checkpoint FOLDER [--size full] [--dataset ROOT]

With ``--dataset``, LeRobot's GrootPolicy over it for that LeRobotDataset too (``FOLDER/lerobot_policy``): a GR00T
teacher to distil, made offline (LeRobot's own GR00T processor reads its Qwen3-VL files from the hub).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

QWEN_FOLDER, CHECKPOINT_FOLDER, LEROBOT_POLICY_FOLDER = "qwen3_vl", "gr00t_n1_7", "lerobot_policy"
SPECIAL_TOKENS = [
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
]
WORDS = "user assistant pick place push open the a red blue cube drawer goal . \n".split(" ")
# each image item becomes one vision block, whose <|image_pad|> the processor expands to the image's tokens
CHAT_TEMPLATE = (
    "{% for message in messages %}<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}"
    "{% else %}{% for item in message['content'] %}"
    "{% if item['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif item['type'] == 'video' %}<|vision_start|><|video_pad|><|vision_end|>"
    "{% elif item['type'] == 'text' %}{{ item['text'] }}{% endif %}{% endfor %}{% endif %}"
    "<|im_end|>\n{% endfor %}{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)


@dataclass(frozen=True)
class GrootSize:
    """A Qwen3-VL's text and vision towers and the GR00T N1.7 fields set over GR00T's own defaults."""

    text: dict[str, Any]
    vision: dict[str, Any]
    #: the vocabulary's rows (None: the word-level tokenizer's own size)
    vocab_size: int | None
    #: the image processor's pixel bounds
    pixels: dict[str, int]
    groot: dict[str, Any] = field(default_factory=dict)
    image_size: int = 256
    crop_size: int = 230
    #: the dtype the checkpoint's weights are saved in (GR00T N1.7's own are bfloat16)
    weights_dtype: str = "bfloat16"


_TINY_BLOCKS = dict(positional_embeddings=None, num_attention_heads=2, attention_head_dim=16, final_dropout=True)
SIZES = {
    # Cosmos-Reason2-2B (Qwen3-VL-2B) under GR00T N1.7's defaults: 40-action horizon, 132-wide padding, a 32-block DiT
    "full": GrootSize(
        text=dict(
            hidden_size=2048,
            intermediate_size=6144,
            num_hidden_layers=28,
            num_attention_heads=16,
            num_key_value_heads=8,
            head_dim=128,
            max_position_embeddings=262144,
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 5e6,
                "mrope_section": [24, 20, 20],
                "mrope_interleaved": True,
            },
        ),
        vision=dict(
            depth=24,
            hidden_size=1024,
            intermediate_size=4096,
            num_heads=16,
            out_hidden_size=2048,
            num_position_embeddings=2304,
            deepstack_visual_indexes=[5, 11, 17],
        ),
        vocab_size=151936,
        pixels={"shortest_edge": 65536, "longest_edge": 16777216},
    ),
    # the tests': two text layers of 32, a two-block vision tower, 4-action chunks of 8-wide padding, a two-block DiT
    "tiny": GrootSize(
        text=dict(
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
            num_key_value_heads=1,
            head_dim=16,
            max_position_embeddings=512,
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 1e4,
                "mrope_section": [4, 2, 2],
                "mrope_interleaved": True,
            },
        ),
        vision=dict(
            depth=2,
            hidden_size=16,
            intermediate_size=32,
            num_heads=2,
            out_hidden_size=32,
            num_position_embeddings=16,
            deepstack_visual_indexes=[0],
        ),
        vocab_size=None,
        pixels={"shortest_edge": 32**2, "longest_edge": 64**2},
        groot=dict(
            backbone_embedding_dim=32,
            select_layer=2,
            max_state_dim=8,
            max_action_dim=8,
            action_horizon=4,
            hidden_size=24,
            input_embedding_dim=32,  # the DiT's heads x head width
            max_seq_len=32,
            max_num_embodiments=2,
            num_inference_timesteps=4,
            attn_dropout=0.0,
            state_dropout_prob=0.0,
            diffusion_model_cfg=dict(
                **_TINY_BLOCKS,
                num_layers=2,
                norm_type="ada_norm",
                dropout=0.0,
                output_dim=24,
                interleave_self_attention=True,
            ),
            vl_self_attention_cfg=dict(**_TINY_BLOCKS, num_layers=1, dropout=0.0),
        ),
        image_size=32,
        crop_size=28,
        weights_dtype="float32",
    ),
}


def write_qwen3_vl(directory: Path, size: GrootSize) -> Path:
    """A random Qwen3-VL's config at ``size`` and its processor files (no weights) in ``directory``."""
    from transformers import Qwen2VLImageProcessor, Qwen3VLConfig, Qwen3VLProcessor
    from transformers.models.qwen3_vl.video_processing_qwen3_vl import Qwen3VLVideoProcessor

    from snapflow.adapters.lerobot.smolvlm import word_level_tokenizer

    tokenizer = word_level_tokenizer(
        [*SPECIAL_TOKENS, *WORDS],
        eos_token="<|im_end|>",
        additional_special_tokens=SPECIAL_TOKENS,
        model_max_length=512,
        padding_side="left",
    )
    tokenizer.chat_template = CHAT_TEMPLATE
    patches = dict(patch_size=16, merge_size=2, temporal_patch_size=2, size=size.pixels)
    Qwen3VLProcessor(
        image_processor=Qwen2VLImageProcessor(**patches),
        tokenizer=tokenizer,
        video_processor=Qwen3VLVideoProcessor(**patches),
        chat_template=CHAT_TEMPLATE,
    ).save_pretrained(directory)
    ids = {
        f"{name}_token_id": tokenizer.convert_tokens_to_ids(f"<|{name}|>") for name in ("vision_start", "vision_end")
    }
    Qwen3VLConfig(
        image_token_id=tokenizer.convert_tokens_to_ids("<|image_pad|>"),
        video_token_id=tokenizer.convert_tokens_to_ids("<|video_pad|>"),
        **ids,
        tie_word_embeddings=True,
        text_config=dict(
            vocab_size=size.vocab_size or len(tokenizer),
            **size.text,
            tie_word_embeddings=True,
            pad_token_id=tokenizer.pad_token_id,
        ),
        vision_config=dict(patch_size=16, spatial_merge_size=2, temporal_patch_size=2, **size.vision),
    ).save_pretrained(directory)
    return directory


def write_groot_checkpoint(directory: Path, qwen: Path, size: GrootSize, seed: int = 0) -> Path:
    """A random GR00T N1.7 checkpoint over the Qwen3-VL folder ``qwen`` at ``size``, with the processor sidecars
    LeRobot reads beside it: the image sizes, the horizon, the embodiment."""
    import torch
    from lerobot.policies.groot.groot_n1_7 import GR00TN17, GR00TN17Config

    config = GR00TN17Config(model_name=str(qwen), **size.groot)
    torch.manual_seed(seed)
    model = GR00TN17(config, load_backbone_weights=False).to(getattr(torch, size.weights_dtype))
    model.save_pretrained(directory)
    horizon = config.action_horizon
    processor = {
        "image_target_size": [size.image_size, size.image_size],
        "image_crop_size": [size.crop_size, size.crop_size],
        "max_action_horizon": horizon,
        "modality_configs": {"new_embodiment": {"action": {"delta_indices": list(range(horizon))}}},
    }
    (directory / "processor_config.json").write_text(json.dumps({"processor_kwargs": processor}))
    (directory / "embodiment_id.json").write_text(json.dumps({"new_embodiment": 1}))
    return directory


def write_random_groot(directory: str | Path, size: str = "full") -> Path:
    """The Qwen3-VL folder and the GR00T N1.7 checkpoint over it, inside ``directory``; the checkpoint's folder, which
    ``GrootConfig(base_model_path=...)`` and ``snapflow bench --architecture groot --vlm`` take. Both are named by
    absolute paths, as a hub id names them from anywhere: LeRobot reads a relative one as a hub id."""
    directory, chosen = Path(directory).resolve(), SIZES[size]
    qwen = write_qwen3_vl(directory / QWEN_FOLDER, chosen)
    return write_groot_checkpoint(directory / CHECKPOINT_FOLDER, qwen, chosen)


def write_lerobot_policy(checkpoint: Path, dataset_root: Path, output: Path) -> Path:
    """LeRobot's GrootPolicy over the GR00T N1.7 ``checkpoint`` for the LeRobotDataset at ``dataset_root`` (its state,
    cameras and actions; its statistics in the processors, whose Qwen3-VL step reads the checkpoint's backbone),
    saved as a policy folder at ``output``: the teacher ``snapflow distill --policy`` takes. LeRobot's own
    ``lerobot-train --policy.type=groot`` builds the same, reading the Qwen3-VL processor files from the hub."""
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies.groot.configuration_groot import GrootConfig
    from lerobot.policies.groot.modeling_groot import GrootPolicy

    from snapflow.adapters.lerobot.dataset import policy_features
    from snapflow.adapters.lerobot.groot import groot_processors

    metadata = LeRobotDatasetMetadata(f"local/{dataset_root.name}", root=dataset_root)
    features = policy_features(metadata.features)
    checkpoint_config = json.loads((checkpoint / "config.json").read_text())
    config = GrootConfig(
        base_model_path=str(checkpoint.resolve()),
        max_state_dim=checkpoint_config["max_state_dim"],
        max_action_dim=checkpoint_config["max_action_dim"],
        chunk_size=checkpoint_config["action_horizon"],
        n_action_steps=checkpoint_config["action_horizon"],
        use_bf16=False,  # the CPU's float32; a GPU run may turn it on
        input_features={key: value for key, value in features.items() if value.type is not FeatureType.ACTION},
        output_features={key: value for key, value in features.items() if value.type is FeatureType.ACTION},
    )
    policy = GrootPolicy(config)
    policy.save_pretrained(output)
    for processor in groot_processors(policy, metadata.stats):
        processor.save_pretrained(output)
    return output


def main(arguments: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where the Qwen3-VL folder and the checkpoint go")
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    parser.add_argument(
        "--dataset",
        type=Path,
        metavar="ROOT",
        help="also write LeRobot's GrootPolicy over the checkpoint for this LeRobotDataset (its features and "
        "statistics) in DIRECTORY/lerobot_policy, a teacher for snapflow distill --policy",
    )
    options = parser.parse_args(arguments)
    checkpoint = write_random_groot(options.directory, options.size)
    if options.dataset is not None:
        print(write_lerobot_policy(checkpoint, options.dataset, checkpoint.parent / LEROBOT_POLICY_FOLDER))
    else:
        print(checkpoint)


if __name__ == "__main__":
    main()


__all__ = [
    "GrootSize",
    "SIZES",
    "write_groot_checkpoint",
    "write_lerobot_policy",
    "write_qwen3_vl",
    "write_random_groot",
]
