"""Tiny LeRobot policies built fully offline.

SmolVLA: a SmolVLM config, word-level tokenizer and processor written to a local folder, then LeRobot's
SmolVLAPolicy with load_vlm_weights=False (about 200k parameters). pi0 / pi0.5 (LeRobot >= 0.5): LeRobot's own
PI0Policy / PI05Policy, with the module-level Gemma and PaliGemma config builders (which know only the 2B and
300M variants) shrunk for the build; LeRobot's files are not touched.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Iterator
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
import torch
from packaging.version import Version

from snapflow.adapters.lerobot.pi0 import PI0FlowPolicy
from snapflow.adapters.lerobot.smolvlm import (
    IMAGE_TOKENS,
    OTHER_SPECIAL_TOKENS,
    ROW_COL_TOKENS,
    write_smolvlm,
)
from snapflow.adapters.lerobot_config import SmolVLMSize

try:
    LEROBOT: Version | None = Version(version("lerobot"))
    TRANSFORMERS: Version | None = Version(version("transformers"))
except PackageNotFoundError:  # the adapters' tests skip; the built-in policies' still run
    LEROBOT = TRANSFORMERS = None
# the pi adapters' own minimum, as the registry reads it (0.4.4's pi0 needs a transformers fork)
PI_SKIP = pytest.mark.skipif(
    LEROBOT is None or LEROBOT < Version(PI0FlowPolicy.minimum_lerobot),
    reason=f"LeRobot's pi0 / pi0.5 need lerobot >= {PI0FlowPolicy.minimum_lerobot} (Python >= 3.12, stock "
    f"transformers); {f'lerobot {LEROBOT} is installed' if LEROBOT else 'lerobot is not installed'}",
)

IMAGE_SIZE, PATCH_SIZE, SCALE_FACTOR = 64, 16, 2
# the sizes every tiny LeRobot policy shares: 4-action chunks of 4-D actions, short prompts, CPU, never pushed
TINY_POLICY_SIZES = dict(
    chunk_size=4,
    n_action_steps=4,
    max_state_dim=8,
    max_action_dim=4,
    tokenizer_max_length=16,
    device="cpu",
    push_to_hub=False,
)
WORDS = "pick place push pull open close the a to cube drawer door red green blue goal robot".split()


def write_tiny_smolvlm(directory: Path) -> Path:
    return write_smolvlm(
        directory, WORDS, SmolVLMSize(image_size=IMAGE_SIZE, patch_size=PATCH_SIZE, scale_factor=SCALE_FACTOR)
    )


def build_tiny_smolvla(
    vlm_directory: Path,
    seed: int = 0,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = IMAGE_SIZE,
    action_dim: int = 4,
):
    """A random LeRobot SmolVLAPolicy at tiny size; ``action_dim`` below ``max_action_dim`` (4) pads its chunks, a
    wider one widens it."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    torch.manual_seed(seed)
    config = SmolVLAConfig(
        vlm_model_name=str(vlm_directory),
        load_vlm_weights=False,
        num_vlm_layers=2,
        expert_width_multiplier=0.5,
        resize_imgs_with_padding=(IMAGE_SIZE, IMAGE_SIZE),
        **{**TINY_POLICY_SIZES, "max_action_dim": max(TINY_POLICY_SIZES["max_action_dim"], action_dim)},
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_size, image_size)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
    )
    return SmolVLAPolicy(config)


PI_IMAGE_SIZE = 28  # two 14-pixel SigLIP patches a side


@contextlib.contextmanager
def tiny_pi_configs(policy_type: str) -> Iterator[None]:
    """While active, LeRobot's pi0 / pi0.5 build at tiny size: their PaliGemma/Gemma config builders (which know
    only the 2B and 300M variants) and PaliGemma's image projector (hard-coded to PaliGemma-3B's 2048-wide text)
    are swapped for tiny ones. Needed both to build a tiny policy and to load one back."""
    from lerobot.policies.factory import get_policy_class
    from torch import nn
    from transformers import PaliGemmaConfig
    from transformers.models.auto import CONFIG_MAPPING
    from transformers.models.paligemma import modeling_paligemma

    module = importlib.import_module(get_policy_class(policy_type).__module__)
    sizes = {"gemma_2b": dict(width=64, depth=2, mlp_dim=128), "gemma_300m": dict(width=32, depth=2, mlp_dim=64)}
    vision = dict(
        model_type="siglip_vision_model",
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=1,
        num_attention_heads=2,
        patch_size=14,
        image_size=PI_IMAGE_SIZE,
    )
    projector = modeling_paligemma.PaliGemmaMultiModalProjector

    def tiny_projector(self, config) -> None:
        nn.Module.__init__(self)
        self.linear = nn.Linear(config.vision_config.hidden_size, config.text_config.hidden_size)

    original = module.get_gemma_config, module.CONFIG_MAPPING, projector.__init__
    # 8 heads: LeRobot's joint training forward hard-codes them
    module.get_gemma_config = lambda variant: module.GemmaConfig(
        num_heads=8, num_kv_heads=1, head_dim=8, **sizes[variant]
    )
    module.CONFIG_MAPPING = {
        "paligemma": lambda: PaliGemmaConfig(vision_config=vision),
        "gemma": CONFIG_MAPPING["gemma"],
    }
    projector.__init__ = tiny_projector
    try:
        yield
    finally:
        module.get_gemma_config, module.CONFIG_MAPPING, projector.__init__ = original


def build_tiny_pi(
    policy_type: str,
    seed: int = 0,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = PI_IMAGE_SIZE,
    action_dim: int = 4,
):
    """A random LeRobot PI0Policy ("pi0") or PI05Policy ("pi05") at tiny size (about 40M parameters, nearly all
    in the 257k-token embedding tables); its camera's frames of ``image_size`` are resized to 28 px inside, and an
    ``action_dim`` below ``max_action_dim`` (4) pads its chunks."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_policy_config

    torch.manual_seed(seed)
    config = make_policy_config(
        policy_type,
        image_resolution=(PI_IMAGE_SIZE, PI_IMAGE_SIZE),
        **TINY_POLICY_SIZES,
        dtype="float32",
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_size, image_size)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
    )
    with tiny_pi_configs(policy_type):
        policy = get_policy_class(policy_type)(config)
    with torch.no_grad():  # pi0.5's adaRMS projections start at zero (time ignored): stand in for a trained checkpoint
        for name, parameter in policy.model.paligemma_with_expert.gemma_expert.named_parameters():
            if ".dense." in name:
                parameter.normal_(0, 0.3)
    return policy


def tiny_batch(batch_size: int = 4, seed: int = 0) -> dict[str, torch.Tensor]:
    """What SmolVLA's pre-processor hands the model: normalised state, images in [0, 1], tokens and mask."""
    generator = torch.Generator().manual_seed(seed)
    first_word = (
        2 + len(OTHER_SPECIAL_TOKENS) + len(IMAGE_TOKENS) + len(ROW_COL_TOKENS)
    )  # after [PAD], [UNK] and the special tokens
    tokens = torch.randint(first_word, first_word + len(WORDS), (batch_size, 16), generator=generator)
    mask = torch.arange(16)[None, :] < torch.randint(3, 16, (batch_size, 1), generator=generator)
    return {
        "observation.state": torch.randn(batch_size, 6, generator=generator),
        "observation.images.top": torch.rand(batch_size, 3, IMAGE_SIZE, IMAGE_SIZE, generator=generator),
        "observation.language.tokens": tokens * mask,
        "observation.language.attention_mask": mask,
        "action": torch.randn(batch_size, 4, 4, generator=generator),
    }


def model_inputs(policy, batch: dict[str, torch.Tensor]) -> tuple:
    """What each LeRobot policy's ``predict_action_chunk`` hands its model, written out per policy (not the adapter's
    ``model_inputs``, which the tests check against it)."""
    from snapflow.adapters.lerobot.registry import base_policy_type

    policy_type = base_policy_type(policy.config)
    if policy_type == "groot":  # GR00T's get_action: the backbone's inputs and the action head's
        inputs = policy._filter_groot_inputs(batch, include_action=False)
        return tuple(dict(part) for part in policy._groot_model.prepare_input(inputs))
    if policy_type == "evo1":  # predict_action_chunk's: tasks, cameras, state, embodiments, the action width's mask
        states, _ = policy._prepare_state(batch)
        size = states.shape[0]
        embodiment = policy._get_embodiment_ids(batch, size)
        mask = policy._prepare_inference_action_mask(size)
        return policy._normalize_task_batch(batch), *policy._collect_image_batches(batch), states, embodiment, mask
    if policy_type == "eo1":  # sample_actions': the prompt's tokens, the images, the padded state, placeholder ids
        keys = ("input_ids", "attention_mask", "mm_token_type_ids", "pixel_values", "image_grid_thw")
        state = policy.prepare_state(batch["observation.state"])
        return *(batch[key] for key in keys), state, batch["state_token_id"], batch["action_token_id"]
    if policy_type == "vla_jepa":  # predict_action_chunk's: each sample's cameras, the tasks, the state, (B, 1, D)
        inputs = policy._prepare_model_inputs(batch, training=False)
        cameras = [torch.stack(views) for views in zip(*inputs["images"], strict=True)]
        return cameras, inputs["instructions"], inputs.get("state")
    if policy_type == "molmoact2":  # predict_action_chunk's: the model's inputs and the action width's padding
        return policy._model_inputs(batch), batch.get("action_dim_is_pad")
    language = batch["observation.language.tokens"], batch["observation.language.attention_mask"]
    if policy_type == "multi_task_dit":  # one observation step: the frame gets its steps axis
        frames = {key: batch[key][:, None] for key in ("observation.state", *policy.config.image_features)}
        return (policy._prepare_batch({**batch, **frames}),)
    if policy_type == "xvla":
        inputs = policy._build_model_inputs(batch)
        return tuple(inputs[name] for name in ("input_ids", "image_input", "image_mask", "domain_id", "proprio"))
    if policy_type == "smolvla":
        return *policy.prepare_images(batch), *language, policy.prepare_state(batch)
    state = (policy.prepare_state(batch),) if policy_type == "pi0" else ()  # pi0.5's state is in its prompt
    return *policy._preprocess_images(batch), *language, *state


def lerobot_sample(policy, batch: dict[str, torch.Tensor], noise: torch.Tensor, steps: int) -> torch.Tensor:
    """LeRobot's own Euler sampler on the (possibly wrapped) policy: s = t throughout."""
    policy.config.num_steps = policy.config.num_inference_steps = steps  # SmolVLA's name, pi0's name
    with torch.no_grad():
        return policy.model.sample_actions(*model_inputs(policy, batch), noise=noise)


def randomise_target_time(policy, std: float = 0.2, seed: int = 1):
    """A non-zero phi_s last layer, the same for a given seed: a partly trained student whose output depends on s.
    Works on any policy with a ``target_time_embedding`` (a LeRobot adapter or a SnapFlowPolicy)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in policy.target_time_embedding.linear_out.parameters():
            parameter.copy_(std * torch.randn(parameter.shape, generator=generator))
    return policy


def save_tiny_student(
    vlm_directory: Path,
    directory: Path,
    state_dim: int = 4,
    image_key: str = "observation.image",
    image_size: int = 480,
    action_dim: int = 4,
) -> Path:
    """A distilled tiny SmolVLA (phi_s non-zero) saved by snapflow with unit-statistics processors beside it; by
    default with the features LeRobot's Meta-World env produces (4-D agent state, one 480-pixel
    ``observation.image``, 4-D actions)."""
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_smolvla(
        vlm_directory, state_dim=state_dim, image_key=image_key, image_size=image_size, action_dim=action_dim
    )
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    stats = {"observation.state": {"mean": torch.zeros(state_dim), "std": torch.ones(state_dim)}}
    stats["action"] = {"mean": torch.zeros(action_dim), "std": torch.ones(action_dim)}
    for processor in make_pre_post_processors(policy.config, dataset_stats=stats):
        processor.save_pretrained(directory)
    return directory


def save_tiny_pi_student(
    policy_type: str,
    vlm_directory: Path,
    directory: Path,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = PI_IMAGE_SIZE,
) -> Path:
    """A distilled tiny pi0 / pi0.5 (phi_s non-zero; by default a 6-D state and one ``observation.images.top``) saved
    by snapflow with processors of unit statistics (quantiles too, which pi0.5 normalises by); its tokenizer,
    PaliGemma's hub id, is the tiny one cached under that id. Loading it back needs :func:`tiny_pi_configs`."""
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    cache_as_hub_repo(vlm_directory, "google/paligemma-3b-pt-224")
    policy = build_tiny_pi(policy_type, state_dim=state_dim, image_key=image_key, image_size=image_size)
    with tiny_pi_configs(policy_type):
        save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    unit = {"mean": 0.0, "std": 1.0, "min": -1.0, "max": 1.0, "q01": -1.0, "q99": 1.0, "q10": -0.5, "q90": 0.5}
    stats = {
        key: {name: torch.full((dim,), value) for name, value in unit.items()}
        for key, dim in (("observation.state", state_dim), ("action", 4))
    }
    for processor in make_pre_post_processors(policy.config, dataset_stats=stats):
        processor.save_pretrained(directory)
    return directory


def cache_as_hub_repo(folder: Path, repo_id: str) -> None:
    """Make ``folder`` what an offline ``from_pretrained(repo_id)`` finds in the (test session's) HF cache."""
    import shutil

    from huggingface_hub import constants

    repo = Path(constants.HF_HUB_CACHE) / f"models--{repo_id.replace('/', '--')}"
    revision = "0" * 40
    if not (repo / "snapshots" / revision).is_dir():
        shutil.copytree(folder, repo / "snapshots" / revision)
        (repo / "refs").mkdir(parents=True, exist_ok=True)
        (repo / "refs" / "main").write_text(revision)


def write_tiny_dataset(
    root: Path,
    repo_id: str = "local/tiny",
    episodes: int = 3,
    frames: int = 12,
    fps: int = 10,
    nan_at: int | None = None,
    bimodal: bool = False,
    seed: int = 0,
    mode_per_episode: bool = False,
) -> Path:
    """A LeRobotDataset on disk (images stored in the parquet, no video) whose tasks use the tiny vocabulary;
    ``nan_at`` puts a NaN into that frame's action. ``bimodal``: each action is one of two far-apart values by a coin
    the observation does not show, so the flow from noise to actions curves (one Euler step lands between the
    modes); with ``mode_per_episode`` an episode keeps to one of them (a demonstrator who keeps to one way: the
    episodes alternate, the first one's mode drawn), twin episodes seeing the same frames and task, so that a chunk's
    first actions tell its others and the observation does not."""
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.state": {"dtype": "float32", "shape": (6,), "names": None},
        "observation.images.top": {
            "dtype": "image",
            "shape": (IMAGE_SIZE, IMAGE_SIZE, 3),
            "names": ["height", "width", "channels"],
        },
        "action": {"dtype": "float32", "shape": (4,), "names": None},
    }
    generator = np.random.default_rng(seed)
    dataset = LeRobotDataset.create(
        repo_id=repo_id,
        fps=fps,
        features=features,
        root=root,
        use_videos=False,
        image_writer_threads=0,
        image_writer_processes=0,
    )
    first_mode = None
    for episode in range(episodes):
        # with a mode an episode, episodes come in twins that see the same frames and task in opposite modes: only a
        # chunk's own first actions tell its mode, never the observation
        seen = np.random.default_rng([seed, episode // 2]) if mode_per_episode else generator
        task = (episode // 2 if mode_per_episode else episode) % 3
        for frame in range(frames):
            action = (generator.standard_normal(4) + episode).astype(np.float32)
            if bimodal:
                sign = generator.choice([-1.0, 1.0])
                if mode_per_episode:
                    first_mode = sign if first_mode is None else first_mode
                    sign = first_mode * (-1.0) ** episode
                action = sign * np.array([2.0, -2.0, 1.0, 1.5]) + 0.1 * action
                action = action.astype(np.float32)
            if episode * frames + frame == nan_at:
                action[1] = np.nan
            dataset.add_frame(
                {
                    "observation.state": seen.standard_normal(6).astype(np.float32),
                    "observation.images.top": seen.integers(0, 256, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8),
                    "action": action,
                    "task": ["push the red cube", "open the drawer", "pick the blue cube"][task],
                }
            )
        dataset.save_episode()
    dataset.finalize()  # without it the episode index is never written and loading falls back to the hub
    return root
