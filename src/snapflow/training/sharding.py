"""A student split over the processes of a launch (``snapflow distill --shard``): torch's FSDP2 (``fully_shard``)
shards its weights, gradients and optimizer state, the frozen VLM's included, so that each process holds about
1/N of them and gathers one block at a time as the passes reach it.

The launch is an ordinary multi-process one (``accelerate launch --multi_gpu --num_processes N``, or ``torchrun``):
Accelerate sets up the processes and the trainer shards the model itself, on GPUs and on CPUs (gloo) alike.
Accelerate's own FSDP (``accelerate launch --use_fsdp``) is refused: it does nothing on CPUs (Accelerate 1.16 runs
such a launch as plain data parallelism) and would wrap the model another way on GPUs. Every process draws the step's
global batch and trains on its share (:mod:`snapflow.training.batches`), and FSDP averages the gradients, so a
sharded run takes the steps an unsharded one takes. A checkpoint gathers the whole weights and optimizer state on the
main process, which writes them as an unsharded run does, so it opens and resumes on one process.
"""

from __future__ import annotations

import os
from typing import Any

import torch
from accelerate import Accelerator
from accelerate.utils import convert_outputs_to_fp32
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.objective.base import TwoBranchObjective
from snapflow.policies.checkpoint import untied_names
from snapflow.training.config import TrainConfig

#: what ``accelerate launch --use_fsdp`` (or an accelerate config of ``distributed_type: FSDP``) sets
ACCELERATE_FSDP = "ACCELERATE_USE_FSDP"
#: the first torch whose FSDP2 (``torch.distributed.fsdp.fully_shard``) is public; snapflow runs on older ones unsharded
SHARDING_TORCH = "2.6"


def refuse_accelerate_fsdp() -> None:
    """Refuse a launch that asks for Accelerate's own FSDP: snapflow shards with ``--shard``, one way everywhere."""
    if os.environ.get(ACCELERATE_FSDP, "false").lower() == "true":
        raise InvalidInputError(
            "snapflow does not run under Accelerate's own FSDP (accelerate launch --use_fsdp, or a config with "
            "distributed_type FSDP): launch with --multi_gpu --num_processes N and give snapflow distill --shard"
        )


def check_sharding(processes: int, config: TrainConfig, objective: TwoBranchObjective) -> None:
    """Refuse what sharding cannot run: an older torch, one process, a weight average, an objective that copies the
    student, fp16."""
    if torch.__version__ < SHARDING_TORCH:  # a TorchVersion, compared as a version
        raise InvalidInputError(
            f"--shard needs torch >= {SHARDING_TORCH} (its FSDP2); torch {torch.__version__} is installed"
        )
    if processes < 2:
        raise InvalidInputError(
            "--shard splits the student over the processes of a launch, and this is one process: run it under "
            "accelerate launch --multi_gpu --num_processes N (N >= 2) or torchrun --nproc-per-node N"
        )
    if config.ema_decay is not None:
        raise InvalidInputError(
            "--ema-decay is not supported with --shard: the weight average is not sharded (as LeRobot refuses EMA "
            "under FSDP); distil without one, or without --shard"
        )
    if objective.copies_policy:
        raise InvalidInputError(
            f"{type(objective).__name__} keeps a moving-average copy of the whole student (its target network), "
            "which --shard does not split: distil it without --shard"
        )
    if config.mixed_precision == "fp16":
        raise InvalidInputError("--shard trains in float32 or bf16, not fp16 (its loss scaler is not sharded)")


def shard_units(module: nn.Module) -> list[nn.Module]:
    """The modules each gathered as one block, innermost first: every repeated block (an element of an
    ``nn.ModuleList``: a transformer's layers, the VLM's and the expert's alike) and every leaf module at least as large
    as the largest block (embedding tables, output heads), unless it shares a weight with another module (a head tied
    to its embedding table: one weight is one unit's). The rest (projections, norms, phi_s) stay in the root's unit,
    gathered for the whole step. A block is called through its ``forward``, which is where FSDP gathers it."""
    blocks = [block for child in module.modules() if isinstance(child, nn.ModuleList) for block in child]
    largest = max((_size(block) for block in blocks), default=0)
    names: dict[int, int] = {}
    for _, parameter in module.named_parameters(remove_duplicate=False):
        names[id(parameter)] = names.get(id(parameter), 0) + 1
    chosen = {id(block) for block in blocks if _size(block)}
    chosen |= {
        id(leaf)
        for leaf in module.modules()
        if not list(leaf.children())
        and largest
        and _size(leaf) >= largest
        and all(names[id(parameter)] == 1 for parameter in leaf.parameters())
    }
    # reversed pre-order: every module after its descendants, as fully_shard must meet them
    return [m for m in reversed(list(module.modules())) if id(m) in chosen and m is not module]


def _size(module: nn.Module) -> int:
    return sum(parameter.numel() for parameter in module.parameters())


def shard_module(module: nn.Module, accelerator: Accelerator) -> None:
    """Shard ``module`` in place over the launch's processes: each of :func:`shard_units`, then the rest as the root.
    Its parameters become new (DTensor) ones: an optimizer is made after this. Its forward runs under the launch's
    mixed precision, as ``accelerator.prepare`` would run it."""
    from torch.distributed.device_mesh import init_device_mesh
    from torch.distributed.fsdp import fully_shard

    mesh = init_device_mesh(accelerator.device.type, (accelerator.num_processes,))
    for unit in shard_units(module):
        fully_shard(unit, mesh=mesh)
    fully_shard(module, mesh=mesh)
    if accelerator.mixed_precision != "no":
        module.forward = convert_outputs_to_fp32(accelerator.autocast()(module.forward))


def is_sharded(module: nn.Module) -> bool:
    """Whether :func:`shard_module` sharded ``module``."""
    if torch.__version__ < SHARDING_TORCH:  # a TorchVersion, compared as a version
        return False
    from torch.distributed.fsdp import FSDPModule

    return isinstance(module, FSDPModule)


def gathered_weights(policy: nn.Module) -> dict[str, Tensor]:
    """The whole weights of a sharded ``policy`` on the main process's CPU, each tensor once (a tied one under its first
    name, as :func:`~snapflow.policies.checkpoint.untied_state` keeps it); empty on the others. Every process calls
    it."""
    from torch.distributed.checkpoint.state_dict import get_model_state_dict

    state = get_model_state_dict(policy, options=_gathered())
    return {name: state[name].contiguous() for name in untied_names(policy)} if state else {}


def gathered_optimizer_state(module: nn.Module, optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    """The whole state of ``optimizer`` over a sharded ``module`` on the main process, keyed as an unsharded
    optimizer's ``state_dict()`` (the parameters' positions in its groups); empty on the others. Every process calls
    it."""
    from torch.distributed.checkpoint.state_dict import get_optimizer_state_dict

    state = get_optimizer_state_dict(module, optimizer, options=_gathered())
    if not state:
        return {}
    position = {name: index for index, name in enumerate(_parameter_names(module, optimizer))}
    return {
        "state": {position[name]: entry for name, entry in state["state"].items()},
        "param_groups": [
            {**group, "params": [position[name] for name in group["params"]]} for group in state["param_groups"]
        ],
    }


def load_optimizer_state(module: nn.Module, optimizer: torch.optim.Optimizer, state: dict[str, Any]) -> None:
    """Load a whole optimizer state, keyed as :func:`gathered_optimizer_state` returns it, into the sharded
    ``optimizer`` of ``module``: each process keeps its own shard. Every process calls it."""
    names = _parameter_names(module, optimizer)
    named = {
        "state": {names[int(index)]: entry for index, entry in state["state"].items()},
        "param_groups": [
            {**group, "params": [names[index] for index in group["params"]]} for group in state["param_groups"]
        ],
    }
    from torch.distributed.checkpoint.state_dict import StateDictOptions, set_optimizer_state_dict

    set_optimizer_state_dict(module, optimizer, named, options=StateDictOptions(full_state_dict=True))


def _gathered():
    """A whole copy of the gathered tensors on the main process's CPU, none elsewhere."""
    from torch.distributed.checkpoint.state_dict import StateDictOptions

    return StateDictOptions(full_state_dict=True, cpu_offload=True)


def _parameter_names(module: nn.Module, optimizer: torch.optim.Optimizer) -> list[str]:
    """The names in ``module`` of the optimizer's parameters, in the order of its groups."""
    names = {id(parameter): name for name, parameter in module.named_parameters()}
    return [names[id(parameter)] for group in optimizer.param_groups for parameter in group["params"]]


__all__ = [
    "check_sharding",
    "gathered_optimizer_state",
    "gathered_weights",
    "is_sharded",
    "load_optimizer_state",
    "refuse_accelerate_fsdp",
    "shard_module",
    "shard_units",
]
