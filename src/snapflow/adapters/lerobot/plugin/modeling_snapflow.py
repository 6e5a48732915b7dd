"""The student policies: each declared LeRobot type's policy class (``SnapFlow<stem>Policy`` in this module, where
LeRobot's factory looks) with phi_s attached when built (so LeRobot's ``from_pretrained`` finds it in the model), every
tensor loaded strictly, LeRobot's action API sampling with the config's ``sampling_mode``, and LeRobot's training contract (``forward`` -> loss and logs, ``update`` after each optimiser
step, ``get_optim_params``) running SnapFlow distillation, so ``lerobot-train`` on a student type distils it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow._lazy import resolve
from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.local_vlm import bundled_vlm, resolve_config
from snapflow.adapters.lerobot.plugin.configuration_snapflow import student_config_class
from snapflow.adapters.lerobot.registry import adapter_class, lerobot_time_sampler
from snapflow.adapters.lerobot_types import installed_lerobot_types, lerobot_policy_type
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.objective.base import TwoBranchObjective
from snapflow.objective.options import target_stages
from snapflow.objective.settings import DistillSettings


class NotDistilledError(InvalidInputError):
    """A student whose config says it was never distilled was asked for the one-step jump."""


class SnapFlowStudent:
    """Mixed in before a LeRobot policy class.

    Training (``lerobot-train``): ``forward`` is the objective of the config's ``distill`` settings on the batch
    (SnapFlow's consistency target from the model's own no-grad passes, or a baseline's), as ``snapflow distill``
    computes it; what trains is what those settings say, as the policy is built: the action expert and phi_s
    (``get_optim_params``, and the rest does not require grad), or every parameter where ``freeze_prefix`` is false;
    ``update`` counts the step and records in the config whether the checkpoint was distilled.
    """

    def __init__(self, config: Any, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        adapter = adapter_class(config.base_type)(self)
        # a plain attribute, not a submodule: the adapter holds this policy, and a submodule cycle would recurse
        object.__setattr__(self, "snapflow", adapter)
        adapter.use_sampling_mode(self.requested_sampling_mode)
        adapter.train_prefix = not config.distill.freeze_prefix
        trainable = {id(parameter) for parameter in self.trainable_parameters()}
        for parameter in self.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        self._distilled_by_last_forward = False
        # built once: an objective may hold state across steps (consistency distillation's target network)
        self._objective: tuple[DistillSettings, TwoBranchObjective] | None = None

    snapflow: LeRobotFlowPolicy

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, *, config: Any = None, **kwargs: Any) -> Any:
        """LeRobot's, the config naming a VLM kept inside the local folder ``pretrained_name_or_path`` by its absolute
        path (:func:`~snapflow.adapters.lerobot.local_vlm.resolve_config`): LeRobot builds the model from that name
        and reads a relative one from the working directory. Every LeRobot tool builds a policy from a folder here
        (``make_policy``), after loading its config through the base class's ``PreTrainedConfig.from_pretrained``,
        which a config class of its own cannot hook."""
        if bundled_vlm(pretrained_name_or_path) is not None:
            from lerobot.configs.policies import PreTrainedConfig

            loaded = PreTrainedConfig.from_pretrained(pretrained_name_or_path) if config is None else config
            config = resolve_config(loaded, pretrained_name_or_path)
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model: Any, model_file: str, map_location: str, strict: bool) -> Any:
        # LeRobot loads SmolVLA non-strictly: a missing phi_s would leave it at zero, the naive step under
        # SnapFlow's name
        return super()._load_as_safetensor(model, model_file, map_location, True)

    def requested_sampling_mode(self) -> SamplingMode:
        """The config's ``sampling_mode`` as it reads now (``teacher``: the type's own number of steps);
        ``snapflow-N`` of a student never distilled is refused."""
        mode = self.config.mode.with_own_steps(type(self.snapflow).own_steps(self.config))
        if mode.jump and self.config.distilled is False:
            raise NotDistilledError(
                f"this {self.config.type} policy was not distilled (config distilled=false: a teacher's weights not "
                f"trained by SnapFlow yet, or last trained by flow matching alone), so it has no {mode.name} jump; "
                "sample it as its teacher (sampling_mode=teacher-10) or distil it first (lerobot-train "
                "--policy.path=<this folder>, see the README)"
            )
        return mode

    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        """LeRobot's own, on the batch the adapter says a call on its own needs (LeRobot's policy server asks one
        chunk an observation: a multi-task DiT's observation queues are filled from it first)."""
        return super().predict_action_chunk(self.snapflow.lone_chunk_batch(batch), **kwargs)

    def trainable_parameters(self) -> list[nn.Parameter]:
        """What distillation trains: the action expert, its projections and phi_s (the VLM frozen), or every
        parameter where the config's ``distill.freeze_prefix`` is false."""
        if self.config.distill.freeze_prefix:
            return self.snapflow.expert_parameters()
        return list(self.parameters())

    def get_optim_params(self) -> list[nn.Parameter] | dict[str, nn.Parameter]:
        """:meth:`trainable_parameters`; by name where the policy's own optimizer groups its parameters by name
        (X-VLA's)."""
        trainable = self.trainable_parameters()
        own = super().get_optim_params()
        if isinstance(own, dict):
            ids = {id(parameter) for parameter in trainable}
            return {name: parameter for name, parameter in own.items() if id(parameter) in ids}
        return trainable

    def distillation_objective(self) -> TwoBranchObjective:
        """The objective of the config's ``distill`` settings with the policy's own training times (shifted by
        ``distill.time_shift``), built again only when the settings change."""
        settings = self.config.distill
        if self._objective is None or self._objective[0] != settings:
            self._objective = (settings, settings.objective(lerobot_time_sampler(self.config)))
        return self._objective[1]

    def progress(self) -> float:
        """The fraction of the run done, which a schedule of target steps reads: the config's ``steps_distilled`` of
        its ``distill_steps``; a schedule without them is refused (LeRobot gives a policy no step count)."""
        config = self.config
        if config.distill_steps is not None:
            return config.steps_distilled / config.distill_steps
        if len(target_stages(config.distill.target_steps)) > 1:
            raise InvalidInputError(
                f"a schedule of target steps ({config.distill.target_steps}) splits the run into equal stages: give "
                "lerobot-train its steps as --policy.distill_steps too"
            )
        return 1.0

    def forward(
        self,
        batch: dict[str, Tensor],
        noise: Tensor | None = None,
        time: Tensor | None = None,
        reduction: str = "mean",
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, dict[str, float]]:
        """The distillation loss on a pre-processed batch, and its parts for LeRobot's logs.

        ``noise`` (B, chunk, max_action_dim) and ``time`` (the flow-matching rows' times) are the objective's;
        drawn from ``generator`` (LeRobot's global seed when None) otherwise; a schedule's stage is the one in force
        at :meth:`progress`. The loss is a mean per branch: per-sample losses (``reduction="none"``, LeRobot's sample
        weighting) are refused."""
        if reduction != "mean":
            raise ValueError(f"a SnapFlow student's loss is a mean over its two branches; reduction={reduction!r}")
        objective = self.distillation_objective()
        targets = self.snapflow.action_targets(batch)
        progress = self.progress()
        output = objective(
            self.snapflow, batch, targets, noise=noise, time=time, generator=generator, progress=progress
        )
        self._distilled_by_last_forward = output.num_consistency > 0 and objective.trains_jump
        logs = {
            "flow_matching_loss": output.flow_matching_loss.item(),
            "consistency_loss": output.consistency_loss.item(),
        }
        return output.loss, logs

    def update(self) -> None:
        """Run by ``lerobot-train`` after each optimiser step: counts it (``steps_distilled``), and records whether it
        trained the one-step jump (the config, and so every checkpoint from now on, says distilled) or, with alpha 1
        or lambda 0 and no energy term, flow matching alone (says not distilled: the jump was not trained and phi_s
        drifts)."""
        self.config.steps_distilled += 1
        self.config.distilled = self._distilled_by_last_forward


def student_policy(base_type: str) -> type[SnapFlowStudent]:
    """The student policy class of the declared LeRobot type ``base_type``, made on first use."""
    declared = lerobot_policy_type(base_type)
    name = f"SnapFlow{declared.class_stem}Policy"
    if name not in globals():
        config_class = student_config_class(base_type)
        namespace = {"__module__": __name__, "__qualname__": name, "config_class": config_class}
        made = type(name, (SnapFlowStudent, resolve(declared.policy)), {**namespace, "name": declared.student_type})

        def __init__(self: Any, config: Any, **kwargs: Any) -> None:
            SnapFlowStudent.__init__(self, config, **kwargs)

        # LeRobot reads the config class off the annotation of ``config`` (a string under postponed annotations)
        __init__.__annotations__ = {"config": config_class, "return": None}
        made.__init__ = __init__
        globals()[name] = made
    return globals()[name]


for _declared in installed_lerobot_types():
    student_policy(_declared)


__all__ = ["NotDistilledError", "SnapFlowStudent", "student_policy"]
