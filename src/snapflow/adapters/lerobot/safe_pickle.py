"""Reading what LeRobot's robot client sends without running a client's code.

LeRobot's async-inference protocol pickles its messages (policy instructions, observations), and its server reads them
with ``pickle.loads``: a payload whose ``__reduce__`` names any callable has the server call it. :func:`loads` reads
the same bytes through an unpickler that builds only the types the protocol sends (LeRobot's message dataclasses and
feature types, NumPy arrays and scalars, torch tensors, plain containers) and refuses any other global by name with
:class:`RefusedPayload`, before anything of the payload runs. Tensor storages, which torch pickles as nested
``torch.load`` calls of their own (with ``weights_only=False``), are read by ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import io
import pickle
from typing import Any

import torch

# (module, name) -> what the unpickler may build: every global a RemotePolicyConfig, a TimedObservation (floats,
# strings, NumPy images, tensors) or a list of TimedAction pickles into, under NumPy 1 and 2
_PROTOCOL_TYPES = {
    ("lerobot.async_inference.helpers", "RemotePolicyConfig"),
    ("lerobot.async_inference.helpers", "TimedObservation"),
    ("lerobot.async_inference.helpers", "TimedAction"),
    ("lerobot.configs.types", "PolicyFeature"),
    ("lerobot.configs.types", "FeatureType"),
    ("collections", "OrderedDict"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"),  # an array under pickle protocol 5
    ("numpy._core.numeric", "_frombuffer"),
    ("torch._utils", "_rebuild_tensor_v2"),
}
_TORCH_STORAGE = ("torch.storage", "_load_from_bytes")


class RefusedPayload(pickle.UnpicklingError):
    """A message that names a global LeRobot's protocol never sends: refused before any of it ran."""


def _storage_from_bytes(data: bytes) -> Any:
    """A tensor storage as torch pickles it, read by torch's own weights-only unpickler."""
    return torch.load(io.BytesIO(data), weights_only=True)


class ProtocolUnpickler(pickle.Unpickler):
    """An unpickler that builds only the types of LeRobot's async-inference messages."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == _TORCH_STORAGE:
            return _storage_from_bytes
        if (module, name) in _PROTOCOL_TYPES:
            return super().find_class(module, name)
        raise RefusedPayload(f"refused a message that calls {module}.{name}: not a type LeRobot's protocol sends")


def loads(data: bytes) -> Any:
    """``pickle.loads`` for LeRobot's protocol messages; :class:`RefusedPayload` for anything else."""
    return ProtocolUnpickler(io.BytesIO(data)).load()


__all__ = ["RefusedPayload", "ProtocolUnpickler", "loads"]
