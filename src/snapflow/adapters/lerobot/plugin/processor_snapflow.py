"""The students' processors. ``make_<type>_pre_post_processors``, found by LeRobot's factory when it builds them
fresh (a saved student carries its own): those of the policy it was distilled from, which LeRobot keeps beside its
policy class (``processor_<type>.make_<type>_pre_post_processors``). And :class:`SnapFlowTokenizerStep`, the tokenizer
step of a student folder that keeps its VLM inside: its tokenizer travels in the step's state, so LeRobot's own tools
open the folder from any working directory."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.processor import ProcessorStepRegistry, TokenizerProcessorStep

from snapflow._lazy import resolve
from snapflow.adapters.lerobot_types import installed_lerobot_types, lerobot_policy_type

#: the registry name of :class:`SnapFlowTokenizerStep` in a saved pre-processor
TOKENIZER_STEP = "snapflow_tokenizer_processor"


def student_processors(base_type: str) -> Callable[..., tuple[Any, Any]]:
    """``make_snapflow_<type>_pre_post_processors`` of the declared type ``base_type``, made on first use."""
    declared = lerobot_policy_type(base_type)
    name = f"make_{declared.student_type}_pre_post_processors"
    if name not in globals():
        module = declared.policy.partition(":")[0].replace(".modeling_", ".processor_")

        def make(config: Any, dataset_stats: dict | None = None) -> tuple[Any, Any]:
            return resolve(f"{module}:make_{base_type}_pre_post_processors")(config, dataset_stats)

        make.__name__ = make.__qualname__ = name
        globals()[name] = make
    return globals()[name]


@dataclass
@ProcessorStepRegistry.register(name=TOKENIZER_STEP)
class SnapFlowTokenizerStep(TokenizerProcessorStep):
    """LeRobot's tokenizer step, tokenizing as it does, whose tokenizer's files are its state (each file a uint8
    tensor). LeRobot saves a step's state as a ``.safetensors`` file beside the pipeline's JSON and loads it from the
    policy folder, where it reads LeRobot's own step's ``tokenizer_name`` relative to the working directory: a
    folder naming its VLM ``smolvlm`` opened only from inside it.

    Built from a ``tokenizer`` or a ``tokenizer_name`` as LeRobot's step is, its files are what the tokenizer's
    ``save_pretrained`` writes; built by LeRobot's loader from the JSON, which names no tokenizer, it takes them from
    the state LeRobot hands it next (:meth:`load_state_dict`). :func:`~snapflow.adapters.lerobot.local_vlm.bundle_vlm`
    gives it to the student folders snapflow keeps."""

    _files: dict[str, bytes] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.tokenizer is not None or self.tokenizer_name is not None:
            super().__post_init__()
            self._files = _tokenizer_files(self.input_tokenizer)

    def get_config(self) -> dict[str, Any]:
        """LeRobot's step's settings without a tokenizer's name: the tokenizer is in the state."""
        config = super().get_config()
        config.pop("tokenizer_name", None)
        return config

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The tokenizer's files by name, each as a uint8 tensor of its bytes."""
        return {
            name: torch.from_numpy(np.frombuffer(data, dtype=np.uint8).copy()) for name, data in self._files.items()
        }

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """The tokenizer of the files ``state`` holds (:meth:`state_dict`'s)."""
        from transformers import AutoTokenizer

        self._files = {name: tensor.cpu().numpy().tobytes() for name, tensor in state.items()}
        with tempfile.TemporaryDirectory(prefix="snapflow-tokenizer-") as directory:
            for name, data in self._files.items():
                (Path(directory) / name).write_bytes(data)
            self.input_tokenizer = AutoTokenizer.from_pretrained(directory)


def _tokenizer_files(tokenizer: Any) -> dict[str, bytes]:
    """The files ``tokenizer``'s ``save_pretrained`` writes, by name."""
    with tempfile.TemporaryDirectory(prefix="snapflow-tokenizer-") as directory:
        tokenizer.save_pretrained(directory)
        return {path.name: path.read_bytes() for path in sorted(Path(directory).iterdir()) if path.is_file()}


for _declared in installed_lerobot_types():
    student_processors(_declared)


__all__ = ["TOKENIZER_STEP", "SnapFlowTokenizerStep", "student_processors"]
