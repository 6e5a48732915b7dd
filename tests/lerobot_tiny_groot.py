"""A tiny LeRobot GR00T N1.7 built fully offline (LeRobot >= 0.6): a random two-layer Qwen3-VL (config, word-level
tokenizer with a chat template, image and video processors; no weights) and a random GR00T N1.7 checkpoint over it,
both written to local folders; LeRobot's GrootPolicy loads the checkpoint by its ``base_model_path``."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

QWEN_FOLDER, CHECKPOINT_FOLDER = "tiny_qwen3_vl", "tiny_gr00t_n1_7"
#: GR00T pads state and action to these widths; the tiny policy's own are narrower, so the padding is exercised
MAX_STATE_DIM, MAX_ACTION_DIM, STATE_DIM, ACTION_DIM, HORIZON = 8, 8, 6, 4, 4
IMAGE_KEY, GROOT_IMAGE_SIZE = "observation.images.top", 32
SPECIAL_TOKENS = [
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
]
GROOT_WORDS = "user assistant pick place push open the a red blue cube drawer goal . \n".split(" ")
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


def write_tiny_qwen3_vl(directory: Path, hidden: int = 32) -> Path:
    """A random Qwen3-VL's config (two text layers of ``hidden``, a two-block vision tower) and processor files."""
    from transformers import Qwen2VLImageProcessor, Qwen3VLConfig, Qwen3VLProcessor
    from transformers.models.qwen3_vl.video_processing_qwen3_vl import Qwen3VLVideoProcessor

    from snapflow.adapters.lerobot.smolvlm import word_level_tokenizer

    tokenizer = word_level_tokenizer(
        [*SPECIAL_TOKENS, *GROOT_WORDS],
        eos_token="<|im_end|>",
        additional_special_tokens=SPECIAL_TOKENS,
        model_max_length=512,
        padding_side="left",
    )
    tokenizer.chat_template = CHAT_TEMPLATE
    patches = dict(
        patch_size=16, merge_size=2, temporal_patch_size=2, size={"shortest_edge": 32**2, "longest_edge": 64**2}
    )
    Qwen3VLProcessor(
        image_processor=Qwen2VLImageProcessor(**patches),
        tokenizer=tokenizer,
        video_processor=Qwen3VLVideoProcessor(**patches),
        chat_template=CHAT_TEMPLATE,
    ).save_pretrained(directory)
    head_dim = 16
    ids = {
        f"{name}_token_id": tokenizer.convert_tokens_to_ids(f"<|{name}|>") for name in ("vision_start", "vision_end")
    }
    Qwen3VLConfig(
        image_token_id=tokenizer.convert_tokens_to_ids("<|image_pad|>"),
        video_token_id=tokenizer.convert_tokens_to_ids("<|video_pad|>"),
        **ids,
        tie_word_embeddings=True,
        text_config=dict(
            vocab_size=len(tokenizer),
            hidden_size=hidden,
            intermediate_size=2 * hidden,
            num_hidden_layers=2,
            num_attention_heads=hidden // head_dim,
            num_key_value_heads=1,
            head_dim=head_dim,
            max_position_embeddings=512,
            # the multimodal rotary sections sum to head_dim / 2
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 1e4,
                "mrope_section": [4, 2, 2],
                "mrope_interleaved": True,
            },
            tie_word_embeddings=True,
            pad_token_id=tokenizer.pad_token_id,
        ),
        vision_config=dict(
            depth=2,
            hidden_size=16,
            intermediate_size=32,
            num_heads=2,
            patch_size=16,
            spatial_merge_size=2,
            temporal_patch_size=2,
            out_hidden_size=hidden,
            num_position_embeddings=16,
            deepstack_visual_indexes=[0],
        ),
    ).save_pretrained(directory)
    return directory


def write_tiny_groot_checkpoint(directory: Path, qwen: Path, hidden: int = 32, seed: int = 0) -> Path:
    """A random GR00T N1.7 checkpoint over the Qwen3-VL folder ``qwen`` (4 denoising steps, 4-action chunks, a
    two-block DiT), with the processor sidecars LeRobot reads beside it (tiny images, the horizon, the embodiment)."""
    from lerobot.policies.groot.groot_n1_7 import GR00TN17, GR00TN17Config

    blocks = dict(positional_embeddings=None, num_attention_heads=2, attention_head_dim=16, final_dropout=True)
    config = GR00TN17Config(
        model_name=str(qwen),
        backbone_embedding_dim=hidden,
        select_layer=2,
        max_state_dim=MAX_STATE_DIM,
        max_action_dim=MAX_ACTION_DIM,
        action_horizon=HORIZON,
        hidden_size=24,
        input_embedding_dim=32,  # the DiT's heads x head width
        max_seq_len=32,
        max_num_embodiments=2,
        num_inference_timesteps=4,
        attn_dropout=0.0,
        state_dropout_prob=0.0,
        diffusion_model_cfg=dict(
            **blocks, num_layers=2, norm_type="ada_norm", dropout=0.0, output_dim=24, interleave_self_attention=True
        ),
        vl_self_attention_cfg=dict(**blocks, num_layers=1, dropout=0.0),
    )
    torch.manual_seed(seed)
    GR00TN17(config, load_backbone_weights=False).save_pretrained(directory)
    processor = {
        "image_target_size": [GROOT_IMAGE_SIZE, GROOT_IMAGE_SIZE],
        "image_crop_size": [28, 28],
        "max_action_horizon": HORIZON,
        "modality_configs": {"new_embodiment": {"action": {"delta_indices": list(range(HORIZON))}}},
    }
    (directory / "processor_config.json").write_text(json.dumps({"processor_kwargs": processor}))
    (directory / "embodiment_id.json").write_text(json.dumps({"new_embodiment": 1}))
    return directory


def write_tiny_groot(directory: Path) -> Path:
    """The Qwen3-VL folder and the GR00T checkpoint over it, inside ``directory``; the checkpoint's folder."""
    qwen = write_tiny_qwen3_vl(directory / QWEN_FOLDER)
    return write_tiny_groot_checkpoint(directory / CHECKPOINT_FOLDER, qwen)


def build_tiny_groot(checkpoint: Path, state_dim: int = STATE_DIM, image_key: str = IMAGE_KEY, **options):
    """LeRobot's GrootPolicy (127k parameters) from the tiny checkpoint folder ``checkpoint``, in float32 on the CPU,
    for a ``state_dim``-D state, one camera and 4-D actions; ``options`` are more GrootConfig fields."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.groot.configuration_groot import GrootConfig
    from lerobot.policies.groot.modeling_groot import GrootPolicy

    config = GrootConfig(
        base_model_path=str(checkpoint),
        max_state_dim=MAX_STATE_DIM,
        max_action_dim=MAX_ACTION_DIM,
        chunk_size=HORIZON,
        n_action_steps=HORIZON,
        use_bf16=False,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, GROOT_IMAGE_SIZE, GROOT_IMAGE_SIZE)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **options,
    )
    return GrootPolicy(config)


def tiny_groot_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """GR00T's pre- and post-processors for ``policy`` with [-1, 1] min-max statistics, their Qwen3-VL step reading
    the checkpoint's local Qwen3-VL folder."""
    from snapflow.adapters.lerobot.groot import groot_processors

    stats = {
        key: {"min": torch.full((dim,), -1.0), "max": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }
    return groot_processors(policy, stats)


def raw_groot_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM) -> dict:
    """A raw LeRobot batch for the tiny GR00T's pre-processor: state, one camera in [0, 1], tasks and action chunks."""
    generator = torch.Generator().manual_seed(seed)
    tasks = ["pick the red cube", "open the drawer", "push the blue cube", "place a cube"]
    return {
        "observation.state": torch.rand(batch_size, state_dim, generator=generator) * 2 - 1,
        IMAGE_KEY: torch.rand(batch_size, 3, GROOT_IMAGE_SIZE, GROOT_IMAGE_SIZE, generator=generator),
        "task": [tasks[row % len(tasks)] for row in range(batch_size)],
        "action": torch.rand(batch_size, HORIZON, ACTION_DIM, generator=generator) * 2 - 1,
    }


def groot_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed GR00T batch: its images' patches are flattened across the batch (one
    image a row here), so they are cut by each image's patch count."""
    patches = batch["image_grid_thw"].prod(dim=1).tolist()
    starts = [sum(patches[:row]) for row in range(len(patches) + 1)]
    first, last, _ = rows.indices(len(patches))
    selected = {
        key: value[rows] if torch.is_tensor(value) and key != "pixel_values" else value for key, value in batch.items()
    }
    return {**selected, "pixel_values": batch["pixel_values"][starts[first] : starts[last]]}


def save_tiny_groot_student(checkpoint: Path, directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny GR00T (phi_s non-zero) saved by snapflow with its processors (min-max statistics)."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_groot(checkpoint, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_groot_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_groot",
    "groot_rows",
    "raw_groot_batch",
    "save_tiny_groot_student",
    "tiny_groot_processors",
    "write_tiny_groot",
]
