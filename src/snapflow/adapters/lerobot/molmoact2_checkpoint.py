"""A random MolmoAct2 checkpoint written locally, offline, for LeRobot's MolmoAct2: its Hugging Face config, random
weights, a word-level tokenizer with MolmoAct2's special tokens (image, state, setup, control and action tokens) and
its processor config. LeRobot's ``MolmoAct2Policy`` loads the model *with weights* from ``checkpoint_path`` (strictly:
every key must be there) and its pre-processor reads the tokenizer and image processor from the same folder, so the
folder holds all of them. At full size (a Molmo2-4B-like VLM, SigLIP2-so400m/14 at 378 pixels over Qwen3-4B, and an
action expert of 36 blocks of 1024, one per language layer: 5.73B parameters, 11.5 GB in bfloat16)
``snapflow bench --architecture molmoact2 --vlm FOLDER`` times it with random weights; the tests build a tiny one.

Run as a module::

    python -m snapflow.adapters.lerobot.molmoact2_checkpoint FOLDER [--size full]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: MolmoAct2's image tokens (its processor's ``IMAGE_TOKENS``, in that order) and the prompt's own special tokens
IMAGE_TOKENS = ["<im_patch>", "<im_col>", "<im_start>", "<low_res_im_start>", "<frame_start>", "<im_end>"]
IMAGE_TOKENS += ["<frame_end>", "<im_low>"]
PROMPT_TOKENS = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|image|>", "<action_output>", "<action_start>"]
PROMPT_TOKENS += ["<action_end>", "<state_start>", "<state_end>", "<setup_start>", "<setup_end>", "<control_start>"]
PROMPT_TOKENS += ["<control_end>"]
#: the discretised state's tokens ``<state_0>`` ... (LeRobot's ``num_state_tokens``, 256 by default)
STATE_TOKENS = 256
#: the words of LeRobot's robot prompt and of the tests' tasks (any other word is the tokenizer's [UNK])
WORDS = "user assistant the task is to setup current state of robot expected control mode given these what action"
WORDS += " should take complete image 1 2 3 . , ? pick place push open close a red blue green cube drawer goal"


@dataclass(frozen=True)
class MolmoAct2Size:
    """MolmoAct2's vision tower, its pooling adapter, its language model and its action expert (Hugging Face config
    fields), the image processor's crop, and the dtype the weights are saved in."""

    vit: dict[str, Any]
    adapter: dict[str, Any]
    text: dict[str, Any]
    action_expert: dict[str, Any]
    image_size: int
    #: the vocabulary's rows (None: the word-level tokenizer's own size)
    vocab_size: int | None
    weights_dtype: str = "bfloat16"


SIZES = {
    # a Molmo2-4B-like VLM (SigLIP2-so400m/14 at 378 pixels, its 25 first layers of 27 used; Qwen3-4B) and an action
    # expert of 1024 a block, one block per language layer: LeRobot's defaults for the rest
    "full": MolmoAct2Size(
        vit=dict(hidden_size=1152, intermediate_size=4304, num_hidden_layers=27, num_attention_heads=16),
        adapter=dict(vit_layers=(-3, -9), hidden_size=1152, num_attention_heads=16, intermediate_size=9728),
        text=dict(
            hidden_size=2560,
            num_attention_heads=32,
            num_key_value_heads=8,
            head_dim=128,
            num_hidden_layers=36,
            intermediate_size=9728,
            qkv_bias=False,
            use_qk_norm=True,
            qk_norm_type="qwen3",
            max_position_embeddings=40960,
        ),
        action_expert=dict(hidden_size=1024, num_heads=16, timestep_embed_dim=256),
        image_size=378,
        vocab_size=151936,
    ),
    # the tests': a one-layer vision tower at 28 pixels (one image token), two language layers of 32, two expert
    # blocks of 32
    "tiny": MolmoAct2Size(
        vit=dict(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2),
        adapter=dict(vit_layers=(-1,), hidden_size=16, num_attention_heads=2, intermediate_size=32),
        text=dict(
            hidden_size=32,
            num_attention_heads=2,
            num_key_value_heads=1,
            head_dim=16,
            num_hidden_layers=2,
            intermediate_size=64,
            additional_vocab_size=8,
            max_position_embeddings=512,
        ),
        action_expert=dict(hidden_size=32, num_heads=2, timestep_embed_dim=16, ffn_multiple_of=8),
        image_size=28,
        vocab_size=None,
        weights_dtype="float32",
    ),
}
#: MolmoAct2's pixels (SigLIP2's): 14-pixel patches pooled 2 x 2 into one token
PATCH, POOLING = 14, 2
#: the longest chunk the expert is built for (LeRobot cuts it to the policy's ``chunk_size``)
MAX_ACTION_HORIZON, MAX_ACTION_DIM = 32, 32


def molmoact2_tokenizer() -> Any:
    """A word-level tokenizer with MolmoAct2's special tokens, padding on the left (MolmoAct2's processor inserts its
    BOS after left padding)."""
    from snapflow.adapters.lerobot.smolvlm import word_level_tokenizer

    special = [*IMAGE_TOKENS, *PROMPT_TOKENS, *(f"<state_{index}>" for index in range(STATE_TOKENS))]
    return word_level_tokenizer(
        [*special, *WORDS.split()],
        eos_token="<|endoftext|>",
        additional_special_tokens=special,
        model_max_length=4096,
        padding_side="left",
    )


def hf_config(size: MolmoAct2Size, tokenizer: Any) -> Any:
    """MolmoAct2's Hugging Face config at ``size``, its token ids read from ``tokenizer``: continuous actions only,
    as LeRobot runs it offline (its discrete head's FAST tokenizer is a hub download)."""
    from lerobot.policies.molmoact2.molmoact2_hf_model.configuration_molmoact2 import MolmoAct2Config

    ids = {token: tokenizer.convert_tokens_to_ids(token) for token in (*IMAGE_TOKENS, *PROMPT_TOKENS)}
    vit, text = size.vit, size.text
    vit_head = vit["hidden_size"] // vit["num_attention_heads"]
    patches = size.image_size // PATCH
    return MolmoAct2Config(
        vit_config=dict(
            **vit,
            num_key_value_heads=vit["num_attention_heads"],
            head_dim=vit_head,
            image_default_input_size=(size.image_size, size.image_size),
            image_patch_size=PATCH,
            image_num_pos=patches * patches,
        ),
        adapter_config=dict(
            **size.adapter,
            num_key_value_heads=size.adapter["num_attention_heads"],
            head_dim=size.adapter["hidden_size"] // size.adapter["num_attention_heads"],
            text_hidden_size=text["hidden_size"],
        ),
        text_config=dict(**text, vocab_size=size.vocab_size or len(tokenizer), rope_theta=1e6),
        action_expert_config=dict(**size.action_expert, num_layers=text["num_hidden_layers"]),
        image_start_token_id=ids["<im_start>"],
        low_res_image_start_token_id=ids["<low_res_im_start>"],
        image_end_token_id=ids["<im_end>"],
        image_low_res_id=ids["<im_low>"],
        image_patch_id=ids["<im_patch>"],
        image_col_id=ids["<im_col>"],
        frame_start_token_id=ids["<frame_start>"],
        frame_end_token_id=ids["<frame_end>"],
        max_action_dim=MAX_ACTION_DIM,
        max_action_horizon=MAX_ACTION_HORIZON,
        action_mode="continuous",
        action_output_token_id=ids["<action_output>"],
        action_start_token_id=ids["<action_start>"],
        action_end_token_id=ids["<action_end>"],
        state_start_token_id=ids["<state_start>"],
        state_end_token_id=ids["<state_end>"],
        state_token_start_id=tokenizer.convert_tokens_to_ids("<state_0>"),
        num_state_tokens=STATE_TOKENS,
        eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.pad_token_id,
    )


def processor_config(size: MolmoAct2Size) -> dict[str, Any]:
    """The ``processor_config.json`` LeRobot's MolmoAct2 pre-processor reads: one resized crop an image (MolmoAct2's
    196 tokens of a 378-pixel camera at full size), SigLIP's [-1, 1] pixels."""
    crop = {"height": size.image_size, "width": size.image_size}
    image = dict(
        size=crop,
        image_mean=[0.5] * 3,
        image_std=[0.5] * 3,
        crop_mode="resize",
        max_crops=1,
        patch_size=PATCH,
        pooling_size=[POOLING, POOLING],
    )
    video = dict(size=crop, patch_size=PATCH, pooling_size=[POOLING, POOLING])
    return {"image_processor": image, "video_processor": video, "image_use_col_tokens": True}


def write_random_molmoact2(directory: str | Path, size: str = "full", seed: int = 0) -> Path:
    """A random MolmoAct2 checkpoint at ``size`` (config, weights from ``seed``, tokenizer, processor config) in
    ``directory``, named by its absolute path (LeRobot's ``checkpoint_path`` reads a relative one as a hub id). The
    action expert's matrices are drawn at 1 / sqrt(their fan-in), a trained checkpoint's scale: MolmoAct2 starts its
    modulations and output layer at zero (time and actions ignored) and Hugging Face's init draws every matrix at
    0.02, which leaves a 32-wide expert nearly blind to both."""
    import torch
    from lerobot.policies.molmoact2.molmoact2_hf_model.modeling_molmoact2 import MolmoAct2ForConditionalGeneration

    directory, chosen = Path(directory).resolve(), SIZES[size]
    directory.mkdir(parents=True, exist_ok=True)
    tokenizer = molmoact2_tokenizer()
    tokenizer.save_pretrained(directory)
    (directory / "processor_config.json").write_text(json.dumps(processor_config(chosen), indent=2))
    config = hf_config(chosen, tokenizer)
    dtype = getattr(torch, chosen.weights_dtype)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        default = torch.get_default_dtype()
        torch.set_default_dtype(dtype)  # built in its own dtype: a full-size float32 copy would need twice the memory
        try:
            model = MolmoAct2ForConditionalGeneration(config)
        finally:
            torch.set_default_dtype(default)
        with torch.no_grad():  # the expert's matrices at a trained scale, 1 / sqrt(fan-in)
            for name, parameter in model.named_parameters():
                if name.startswith("model.action_expert.") and parameter.ndim == 2:
                    parameter.normal_(0.0, parameter.shape[1] ** -0.5)
    model.save_pretrained(directory)
    return directory


def parameter_count(size: str = "full") -> dict[str, int]:
    """The parameters of a MolmoAct2 at ``size`` by part, computed from its config without building it (a full-size
    build takes 22.9 GB in float32): the vision tower's layers that run, the pooling adapter, the language model
    (its embedding, which MolmoAct2 does not tie to its output head, and the head) and the action expert."""
    chosen = SIZES[size]
    vit, adapter, text, expert = chosen.vit, chosen.adapter, chosen.text, chosen.action_expert
    width, layers = vit["hidden_size"], vit["num_hidden_layers"]
    used = max(layer if layer >= 0 else layer + layers for layer in adapter["vit_layers"]) + 1
    block = 4 * (width * width + width) + 2 * width * vit["intermediate_size"] + vit["intermediate_size"] + 5 * width
    patches = (chosen.image_size // PATCH) ** 2
    vision = patches * width + (PATCH * PATCH * 3 + 1) * width + used * block
    pool_in, pooled = width * len(adapter["vit_layers"]), adapter["hidden_size"]
    hidden, inner = text["hidden_size"], adapter["intermediate_size"]
    connector = 3 * (pool_in * pooled + pooled) + pooled * pooled + pooled + 2 * pooled * inner + inner * hidden
    vocab = chosen.vocab_size or len(molmoact2_tokenizer())
    extra = text.get("additional_vocab_size", 128)
    heads, kv, head = text["num_attention_heads"], text["num_key_value_heads"], text["head_dim"]
    qkv = (heads + 2 * kv) * head
    norms = 2 * head if text.get("use_qk_norm") else 0
    layer = hidden * qkv + (qkv if text.get("qkv_bias", True) else 0) + heads * head * hidden + norms + 2 * hidden
    layer += 3 * hidden * text["intermediate_size"]
    language = (vocab + extra) * hidden + text["num_hidden_layers"] * layer + hidden + hidden * vocab
    return {
        "vision": vision,
        "connector": connector,
        "language": language,
        "action_expert": _expert_parameters(expert, text["num_hidden_layers"], kv * head),
    }


def _expert_parameters(expert: dict[str, Any], layers: int, kv_width: int) -> int:
    """MolmoAct2's ``ActionExpert``: time MLP, action and context projections, its blocks (self- and
    cross-attention, SwiGLU, a 9-way modulation) and the output layer."""
    width, time = expert["hidden_size"], expert["timestep_embed_dim"]
    multiple = expert.get("ffn_multiple_of", 256)
    inner = -(-int(width * expert.get("mlp_ratio", 8 / 3)) // multiple) * multiple
    linear = width * width + width
    block = 3 * linear + 3 * linear + 2 * (width * inner + inner) + inner * width + width + 9 * linear
    edges = (time * width + width) + linear + (MAX_ACTION_DIM * width + width) + 2 * kv_width * width
    return edges + layers * block + 2 * linear + width * MAX_ACTION_DIM + MAX_ACTION_DIM


def main(arguments: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="where the MolmoAct2 checkpoint folder goes")
    parser.add_argument("--size", choices=sorted(SIZES), default="full")
    options = parser.parse_args(arguments)
    print(write_random_molmoact2(options.directory, options.size))


if __name__ == "__main__":
    main()


__all__ = ["MolmoAct2Size", "SIZES", "hf_config", "molmoact2_tokenizer", "parameter_count", "write_random_molmoact2"]
