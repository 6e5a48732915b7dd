"""The LeRobot policy types snapflow distils, each declared once, in plain Python: the CLI, bench and the
architectures list read them before LeRobot (or torch) is imported, and without LeRobot installed.

A declaration names LeRobot's config and policy classes and snapflow's adapter (``"module:name"``, resolved on first
use); from it follow the adapter registry (:mod:`snapflow.adapters.lerobot.registry`), the student type
``snapflow_<name>`` that LeRobot's tools load (:mod:`snapflow.adapters.lerobot.plugin`), ``snapflow bench
--architecture <name>`` and, where ``trains_from_scratch``, ``snapflow train --policy-type <name>``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from snapflow.errors import InvalidInputError


@dataclass(frozen=True)
class LeRobotPolicyType:
    """One LeRobot policy type under SnapFlow."""

    #: LeRobot's name of the type (``config.type``)
    name: str
    #: the stem of the student's class names: ``SnapFlow<stem>Config`` and ``SnapFlow<stem>Policy``
    class_stem: str
    #: LeRobot's config class, ``"module:Class"``
    config: str
    #: LeRobot's policy class, ``"module:Class"``
    policy: str
    #: snapflow's adapter, a :class:`~snapflow.adapters.lerobot.base.LeRobotFlowPolicy` subclass, ``"module:Class"``
    adapter: str
    #: ``snapflow train --dataset`` trains it from scratch (over a SmolVLM written locally: its adapter's
    #: ``scratch_config``)
    trains_from_scratch: bool = False
    #: config options of a full-size build with random weights (``snapflow bench --architecture``)
    architecture_options: dict[str, Any] = field(default_factory=dict)
    #: the config field naming the VLM whose config and processor a build reads (``bench --vlm``), if any; several
    #: where the policy names its encoders apart (multi-task DiT's CLIP vision and text)
    vlm_option: str | tuple[str, ...] | None = None
    #: the paper's A800 figures for this architecture, which ``snapflow bench`` prints beside its own
    paper_latency: dict[str, float] | None = None

    @property
    def vlm_options(self) -> tuple[str, ...]:
        """:attr:`vlm_option` as a tuple (empty where the build reads no VLM)."""
        return (self.vlm_option,) if isinstance(self.vlm_option, str) else tuple(self.vlm_option or ())

    @property
    def student_type(self) -> str:
        """The LeRobot type a distilled student of this type is saved as."""
        return f"snapflow_{self.name}"


LEROBOT_POLICY_TYPES: dict[str, LeRobotPolicyType] = {}


def register_lerobot_policy_type(declaration: LeRobotPolicyType) -> None:
    """Declare a LeRobot policy type (see the module's description)."""
    if declaration.name in LEROBOT_POLICY_TYPES:
        raise ValueError(f"a LeRobot policy type named {declaration.name!r} is declared already")
    LEROBOT_POLICY_TYPES[declaration.name] = declaration


#: LeRobot's other policy types (0.4.4's and 0.6's), each with why snapflow does not distil it: no velocity field for
#: a jump to replace, or one that no adapter reaches yet (issue 58 surveys them)
NOT_DISTILLED: dict[str, str] = {
    "pi0_fast": "autoregressive: it decodes FAST action tokens one at a time, with no velocity field to jump along",
    "act": "a transformer that regresses its action chunk in one pass: there are no denoising steps to cut",
    "diffusion": "a DDPM / DDIM denoiser of noise, not a flow-matching velocity field, which SnapFlow's jump averages",
    "vqbet": "a behaviour transformer over discrete action codes: no ODE",
    "tdmpc": "a model-based planner (TD-MPC): no ODE",
    "gaussian_actor": "one Gaussian over the actions: no ODE",
    "sac": "a soft actor-critic's actor, one Gaussian over the actions: no ODE",
    "reward_classifier": "a reward model, not a policy",
    "sarm": "a reward model (stage-aware), not a policy",
    "wall_x": "flow-matching (10 steps), but it needs peft, torchdiffeq and qwen-vl-utils and a custom MoE checkpoint "
    "folder, and runs its whole LLM every step: there is no prefix to encode once",
    "fastwam": "flow-matching (10-20 steps), but it loads its Wan2.2 VAE by a hard-coded hub id, so it cannot be built "
    "offline",
    "lingbot_va": "a video world model: its action chunk waits on its own video denoising steps (20 video + 50 "
    "action), which a jump of the action flow does not remove",
}


def lerobot_policy_type(name: str) -> LeRobotPolicyType:
    """The declared type ``name``, or an :class:`InvalidInputError` listing the declared ones and saying why
    ``name`` is not among them where that is known."""
    if name not in LEROBOT_POLICY_TYPES:
        why = f": {NOT_DISTILLED[name]}" if name in NOT_DISTILLED else ""
        raise InvalidInputError(
            f"snapflow distills LeRobot's {', '.join(sorted(LEROBOT_POLICY_TYPES))} policies, not {name!r}{why}"
        )
    return LEROBOT_POLICY_TYPES[name]


#: the first LeRobot whose tools (lerobot-eval, lerobot-train, its policy server) load third-party policy types, and so
#: the student types ``snapflow_<name>``
PLUGIN_LEROBOT = "0.5"


def lerobot_loads_plugins() -> bool:
    """Whether the installed LeRobot's tools load the student types (lerobot >= :data:`PLUGIN_LEROBOT`)."""
    from importlib.metadata import version

    from packaging.version import Version

    return Version(version("lerobot")) >= Version(PLUGIN_LEROBOT)


def installed_lerobot_types() -> tuple[str, ...]:
    """The declared types the installed LeRobot ships (lerobot 0.4.4 has no multi-task DiT, for one): the ones whose
    student types the plugin makes."""
    from importlib.util import find_spec

    def ships(declared: LeRobotPolicyType) -> bool:
        try:
            return find_spec(declared.config.partition(":")[0]) is not None
        except ModuleNotFoundError:  # its policy package is missing altogether
            return False

    return tuple(name for name, declared in LEROBOT_POLICY_TYPES.items() if ships(declared))


def lerobot_teachers() -> tuple[str, ...]:
    """The LeRobot types ``snapflow train --dataset`` trains from scratch."""
    return tuple(name for name, declared in LEROBOT_POLICY_TYPES.items() if declared.trains_from_scratch)


register_lerobot_policy_type(
    LeRobotPolicyType(
        "pi0",
        "PI0",
        "lerobot.policies.pi0.configuration_pi0:PI0Config",
        "lerobot.policies.pi0.modeling_pi0:PI0Policy",
        "snapflow.adapters.lerobot.pi0:PI0FlowPolicy",
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "pi05",
        "PI05",
        "lerobot.policies.pi05.configuration_pi05:PI05Config",
        "lerobot.policies.pi05.modeling_pi05:PI05Policy",
        "snapflow.adapters.lerobot.pi0:PI05FlowPolicy",
        paper_latency={
            "teacher_10_ms": 274.0,
            "snapflow_1_ms": 83.0,
            "denoising_share_10": 241.0 / 274.0,
            "per_step_ms": 23.0,
        },
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "smolvla",
        "SmolVLA",
        "lerobot.policies.smolvla.configuration_smolvla:SmolVLAConfig",
        "lerobot.policies.smolvla.modeling_smolvla:SmolVLAPolicy",
        "snapflow.adapters.lerobot.smolvla:SmolVLAFlowPolicy",
        trains_from_scratch=True,
        architecture_options={"load_vlm_weights": False},  # timing reads the VLM's config, never its weights
        vlm_option="vlm_model_name",
        paper_latency={"teacher_10_ms": 178.0, "snapflow_1_ms": 50.0},
    )
)
#: X-VLA-0.9B's VLM, Florence-2-large's encoder side (a DaViT and BART-large's encoder), in transformers' own format:
#: what ``snapflow bench --architecture xvla`` builds with random weights (X-VLA's config names no default)
XVLA_FLORENCE_LARGE: dict[str, Any] = {
    "vision_config": {
        "depths": [1, 1, 9, 1],
        "embed_dim": [256, 512, 1024, 2048],
        "num_heads": [8, 16, 32, 64],
        "num_groups": [8, 16, 32, 64],
        "window_size": 12,
        "projection_dim": 1024,
    },
    "text_config": {"d_model": 1024, "encoder_layers": 12, "decoder_layers": 12, "vocab_size": 51289},
}
register_lerobot_policy_type(
    LeRobotPolicyType(
        "xvla",
        "XVLA",
        "lerobot.policies.xvla.configuration_xvla:XVLAConfig",
        "lerobot.policies.xvla.modeling_xvla:XVLAPolicy",
        "snapflow.adapters.lerobot.xvla:XVLAFlowPolicy",
        trains_from_scratch=True,
        architecture_options={"florence_config": XVLA_FLORENCE_LARGE, "action_mode": "auto"},
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "multi_task_dit",
        "MultiTaskDiT",
        "lerobot.policies.multi_task_dit.configuration_multi_task_dit:MultiTaskDiTConfig",
        "lerobot.policies.multi_task_dit.modeling_multi_task_dit:MultiTaskDiTPolicy",
        "snapflow.adapters.lerobot.multi_task_dit:MultiTaskDiTFlowPolicy",
        architecture_options={"objective": "flow_matching"},
        vlm_option=("vision_encoder_name", "text_encoder_name"),
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "groot",
        "Groot",
        "lerobot.policies.groot.configuration_groot:GrootConfig",
        "lerobot.policies.groot.modeling_groot:GrootPolicy",
        "snapflow.adapters.lerobot.groot:GrootFlowPolicy",
        # GR00T builds only from a checkpoint folder, whose config names its Qwen3-VL backbone: bench --vlm gives it
        vlm_option="base_model_path",
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "evo1",
        "Evo1",
        "lerobot.policies.evo1.configuration_evo1:Evo1Config",
        "lerobot.policies.evo1.modeling_evo1:Evo1Policy",
        "snapflow.adapters.lerobot.evo1:Evo1FlowPolicy",
        # EVO1 loads its InternVL3 with weights: bench --vlm gives a random one written locally (evo1_checkpoint)
        vlm_option="vlm_model_name",
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "eo1",
        "EO1",
        "lerobot.policies.eo1.configuration_eo1:EO1Config",
        "lerobot.policies.eo1.modeling_eo1:EO1Policy",
        "snapflow.adapters.lerobot.eo1:EO1FlowPolicy",
        # EO-1 loads its Qwen2.5-VL with weights and processor: bench --vlm gives a random one written locally
        # (eo1_checkpoint)
        vlm_option="vlm_base",
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "vla_jepa",
        "VLAJEPA",
        "lerobot.policies.vla_jepa.configuration_vla_jepa:VLAJEPAConfig",
        "lerobot.policies.vla_jepa.modeling_vla_jepa:VLAJEPAPolicy",
        "snapflow.adapters.lerobot.vla_jepa:VLAJEPAFlowPolicy",
        # timing builds it without its world model (a V-JEPA 2 and a predictor: a training-time loss sampling never
        # runs); it loads its Qwen3-VL with weights: bench --vlm gives a random one written locally
        # (vla_jepa_checkpoint)
        architecture_options={"enable_world_model": False},
        vlm_option="qwen_model_name",
    )
)
register_lerobot_policy_type(
    LeRobotPolicyType(
        "molmoact2",
        "MolmoAct2",
        "lerobot.policies.molmoact2.configuration_molmoact2:MolmoAct2Config",
        "lerobot.policies.molmoact2.modeling_molmoact2:MolmoAct2Policy",
        "snapflow.adapters.lerobot.molmoact2:MolmoAct2FlowPolicy",
        # continuous actions only (its discrete head's FAST tokenizer is a hub download), in float32 as bench times
        architecture_options={
            "action_mode": "continuous",
            "inference_action_mode": "continuous",
            "model_dtype": "float32",
        },
        # MolmoAct2 loads its whole checkpoint with weights: bench --vlm gives a random one written locally
        # (molmoact2_checkpoint)
        vlm_option="checkpoint_path",
    )
)


__all__ = [
    "LeRobotPolicyType",
    "LEROBOT_POLICY_TYPES",
    "register_lerobot_policy_type",
    "lerobot_policy_type",
    "lerobot_teachers",
    "NOT_DISTILLED",
    "PLUGIN_LEROBOT",
    "lerobot_loads_plugins",
    "installed_lerobot_types",
]
