"""Training loop for teachers (flow matching) and students (SnapFlow), on Hugging Face Accelerate.

Everything random in step k comes from generators seeded by (seed, k) (:mod:`snapflow.training.batches`), and the
learning rate is a function of k, so ``resume`` continues the same loss curve. ``TrainConfig.batch_size`` is the
step's global batch: under ``accelerate launch`` every process draws the same global batch (its indices, noise and
flow-matching times) and trains on its own share of the rows, laid out as the objective lays out a batch
(flow-matching rows first), and Accelerate averages the gradients; so P processes take the steps one process takes, up to floating-point rounding. Draws an objective makes
inside its one-step rows (MeanFlow's times, say) come from a generator of (seed, process, k) on the processes after
the first. Where a run starts (fresh or resumed) and each checkpoint it saves are :mod:`snapflow.training.resuming`'s;
a student sharded over the processes (``shard``), :mod:`snapflow.training.sharding`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any, Protocol

import torch
from accelerate import Accelerator, PartialState
from accelerate.utils import parse_flag_from_env
from torch import Tensor, nn
from tqdm.auto import tqdm

from snapflow.objective.base import TwoBranchObjective
from snapflow.protocol import map_tensors
from snapflow.reporting.files import write_json
from snapflow.reporting.locks import hold_run_lock
from snapflow.training.batches import draw_batch, share_of_batch, step_generator
from snapflow.training.config import TrainConfig
from snapflow.training.resuming import continue_from_kept, keeping_each_checkpoint, save_run_checkpoint, start_run
from snapflow.training.sharding import check_sharding, refuse_accelerate_fsdp

HISTORY = "history.json"  # the run's losses and validation, written when training reaches its last step


class ObjectiveModule(nn.Module):
    """Policy + objective behind one ``forward``, so data-parallel wrappers see every pass."""

    def __init__(self, policy: nn.Module, objective: TwoBranchObjective) -> None:
        super().__init__()
        self.policy = policy
        self.objective = objective

    def forward(
        self,
        observation: Any,
        actions: Tensor,
        noise: Tensor | None = None,
        time: Tensor | None = None,
        generator: torch.Generator | None = None,
        progress: float = 1.0,
    ) -> tuple[Tensor, Tensor, Tensor]:
        output = self.objective(
            self.policy, observation, actions, noise=noise, time=time, generator=generator, progress=progress
        )
        return output.loss, output.flow_matching_loss, output.consistency_loss


class ChunkSource(Protocol):
    """What the trainer draws batches from: ``len()`` and ``batch(indices) -> (observation, actions)``."""

    def __len__(self) -> int: ...

    def batch(self, indices: Tensor) -> tuple[Any, Tensor]: ...


def launch_state() -> PartialState:
    """The processes of the launch as the trainer's ``Accelerator`` sees them, before it is made: on CPUs too, where a
    bare ``PartialState()`` is one process (Accelerate reads ``ACCELERATE_USE_CPU`` in ``Accelerator`` only)."""
    return PartialState(cpu=parse_flag_from_env("ACCELERATE_USE_CPU"))


def train_step(
    module: nn.Module,
    optimizer: torch.optim.Optimizer,
    observation: Any,
    actions: Tensor,
    *,
    learning_rate: float,
    grad_clip: float = 0.0,
    noise: Tensor | None = None,
    time: Tensor | None = None,
    generator: torch.Generator | None = None,
    progress: float = 1.0,
    accelerator: Accelerator | None = None,
) -> Tensor:
    """One optimisation step of an :class:`ObjectiveModule` (or its data-parallel wrapper): the objective, backward,
    gradient clipping (``grad_clip`` > 0) and the optimizer at ``learning_rate``. Returns [loss, FM loss, one-step
    loss], detached and on the device (read them back only when logging: ``.item()`` per step syncs a GPU).

    ``noise`` and ``time`` are drawn by the objective from ``generator`` when not given. The trainer, the toy
    experiment and the training-cost benchmark all step through here.
    """
    for group in optimizer.param_groups:
        group["lr"] = learning_rate
    module.train()
    loss, fm, sc = module(observation, actions, noise, time, generator, progress)
    optimizer.zero_grad(set_to_none=True)
    if accelerator is not None:
        accelerator.backward(loss)
    else:
        loss.backward()
    if grad_clip:
        parameters = [p for group in optimizer.param_groups for p in group["params"]]
        if accelerator is not None:
            accelerator.clip_grad_norm_(parameters, grad_clip)
        else:
            torch.nn.utils.clip_grad_norm_(parameters, grad_clip)
    optimizer.step()
    return torch.stack([loss.detach(), fm, sc])


def _to(device: torch.device, observation: Any, *tensors: Tensor):
    """Move the tensors of a batch (other entries, such as LeRobot's task strings, stay as they are)."""
    return map_tensors(observation, lambda tensor: tensor.to(device)), *(t.to(device) for t in tensors)


@torch.no_grad()
def validation_loss(
    module: ObjectiveModule,
    data: ChunkSource,
    batch_size: int,
    device: torch.device,
    batches: int = 8,
    progress: float = 1.0,
) -> dict[str, float]:
    """Objective on held-out chunks with fixed draws, so values are comparable across steps and runs (with a
    scheduled objective, across runs at the same ``progress``)."""
    generator = torch.Generator().manual_seed(12345)
    totals = torch.zeros(3)
    for _ in range(batches):
        observation, actions, noise, time = _to(
            device, *draw_batch(module.policy, module.objective, data, batch_size, generator)
        )
        totals += torch.stack(
            [value.float().cpu() for value in module(observation, actions, noise, time, generator, progress)]
        )
    loss, fm, sc = (totals / batches).tolist()
    return {"loss": loss, "flow_matching": fm, "consistency": sc}


def train(
    policy: nn.Module,
    objective: TwoBranchObjective,
    train_data: ChunkSource,
    val_data: ChunkSource | None,
    config: TrainConfig,
    run_directory: str | Path,
    metadata: dict[str, Any],
    resume: bool = False,
    trainable: list[nn.Parameter] | None = None,
    progress: bool = True,
    *,
    holder: str,
    on_checkpoint: Callable[[Path], None] | None = None,
    keep_progress: str | Path | None = None,
    shard: bool = False,
) -> dict[str, Any]:
    """Optimise ``objective`` on ``policy``; checkpoints under ``run_directory/checkpoints``. Holds the run folder
    for the whole run: another process training into it is refused with
    :class:`~snapflow.reporting.locks.RunLockedError`, which names ``holder``.

    Args:
        policy: any module implementing :class:`~snapflow.protocol.FlowPolicy` (SnapFlowPolicy, an adapter).
        objective: the loss (SnapFlowObjective; ``alpha=1`` trains a flow-matching teacher).
        train_data: what batches are drawn from: ``len()`` and ``batch(indices) -> (observation, actions)``.
        val_data: held-out chunks of the same kind, for the validation loss; None: no validation.
        config: the optimisation settings.
        run_directory: the run folder: ``checkpoints/``, ``latest.json`` and, at the end, ``history.json``.
        metadata: the policy description saved beside the weights (see ``policy_metadata``); its ``stage``, if
            any, names the progress bar.
        resume: continue from the run folder's latest checkpoint, under the same settings; without it a folder
            that holds a run is refused.
        trainable: the optimised parameters (a policy's ``expert_parameters()``); None: all of them.
        progress: show a progress bar.
        holder: the command that trains (e.g. ``snapflow train``), named to another process that tries the folder.
        on_checkpoint: called with each checkpoint once it is whole and marked latest (a sweep keeps a copy).
        keep_progress: a folder that holds a copy of the latest checkpoint, all that resuming reads (the previous
            copy removed), to commit or carry to another machine; with ``resume``, a run folder without a
            checkpoint of its own continues from the one kept there.
        shard: split the policy's weights, gradients and optimizer state over the processes of the launch
            (:mod:`snapflow.training.sharding`), for a policy that does not fit one device.

    Returns:
        The trainer state: ``step``, ``history`` (a loss row every ``log_every`` steps), ``validation``,
        ``train_config`` and ``wall_time_s``.

    Examples:
        Four steps of a tiny MLP student on random chunks in a throw-away run folder: a loss row every two steps,
        a validation loss and a checkpoint at the last one.

        >>> import tempfile
        >>> from pathlib import Path
        >>> import torch
        >>> from snapflow import SnapFlowObjective, SnapFlowPolicy
        >>> from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
        >>> from snapflow.training.config import TrainConfig
        >>> from snapflow.training.trainer import train
        >>> class Chunks:  # len() and batch(indices) -> (observation, actions)
        ...     def __init__(self, size):
        ...         self.observation = torch.randn(size, 4)
        ...         self.actions = torch.randn(size, 3, 2)
        ...     def __len__(self):
        ...         return len(self.actions)
        ...     def batch(self, indices):
        ...         return self.observation[indices], self.actions[indices]
        >>> config = MLPPolicyConfig(observation_dim=4, action_dim=2, chunk_length=3)
        >>> student = SnapFlowPolicy(MLPFlowModel(config))
        >>> settings = TrainConfig(steps=4, batch_size=8, log_every=2)
        >>> with tempfile.TemporaryDirectory() as run:
        ...     state = train(
        ...         student, SnapFlowObjective(), Chunks(32), Chunks(8), settings, run,
        ...         metadata={}, progress=False, holder="an example",
        ...     )
        ...     sorted(path.name for path in Path(run, "checkpoints").iterdir())
        ['step_0000004']
        >>> [row["step"] for row in state["history"]], state["validation"][-1]["step"]
        ([2, 4], 4)
    """
    run_directory = Path(run_directory)
    accelerator = _accelerator(config, objective, shard)  # what it refuses, before the run folder is touched
    # only the main process writes the run, so only it holds the folder (the processes of one launch would otherwise
    # refuse each other)
    with hold_run_lock(run_directory, holder) if accelerator.is_main_process else nullcontext():
        return _train(
            accelerator,
            policy,
            objective,
            train_data,
            val_data,
            config,
            run_directory,
            metadata,
            resume,
            trainable,
            progress,
            on_checkpoint,
            keep_progress,
            shard,
        )


def _accelerator(config: TrainConfig, objective: TwoBranchObjective, shard: bool) -> Accelerator:
    """The launch's Accelerator, once what the launch cannot train is refused: Accelerate's own FSDP, a batch that does
    not split over the processes, what sharding cannot run."""
    refuse_accelerate_fsdp()
    accelerator = Accelerator(mixed_precision=config.mixed_precision)
    share_of_batch(config.batch_size, accelerator.num_processes)
    if shard:
        check_sharding(accelerator.num_processes, config, objective)
    return accelerator


def _history_row(
    accelerator: Accelerator, running: list[Tensor], step: int, learning_rate: float, schedule: dict[str, Any]
) -> dict[str, Any]:
    """The mean [loss, FM loss, one-step loss] of the steps since the last row, over every process's rows (each
    process's loss is the mean of its equal share: their mean is the global batch's), logged at ``step``."""
    mean = accelerator.reduce(torch.stack(running).float().mean(0), reduction="mean")
    loss, flow_matching, consistency = mean.tolist()
    return {
        "step": step,
        "loss": loss,
        "flow_matching": flow_matching,
        "consistency": consistency,
        "lr": learning_rate,
        **schedule,
    }


def _validation_row(
    accelerator: Accelerator, module: nn.Module, val_data: ChunkSource, batch_size: int, step: int, progress: float
) -> dict[str, Any]:
    """:func:`validation_loss` of the (possibly wrapped) ``module`` at ``step``."""
    module.eval()
    loss = validation_loss(
        accelerator.unwrap_model(module), val_data, batch_size, accelerator.device, progress=progress
    )
    return {"step": step, **loss}


def _train(
    accelerator: Accelerator,
    policy: nn.Module,
    objective: TwoBranchObjective,
    train_data: ChunkSource,
    val_data: ChunkSource | None,
    config: TrainConfig,
    run_directory: Path,
    metadata: dict[str, Any],
    resume: bool,
    trainable: list[nn.Parameter] | None,
    progress: bool,
    on_checkpoint: Callable[[Path], None] | None,
    keep_progress: str | Path | None,
    shard: bool,
) -> dict[str, Any]:
    """:func:`train` with the run folder held."""
    if keep_progress is not None:
        if resume and accelerator.is_main_process:
            continue_from_kept(accelerator, run_directory, Path(keep_progress), config)
        accelerator.wait_for_everyone()
        on_checkpoint = keeping_each_checkpoint(Path(keep_progress), on_checkpoint)
    state, module, optimizer, average = start_run(
        accelerator, ObjectiveModule(policy, objective), trainable, config, run_directory, resume, shard
    )
    device = accelerator.device
    started = time.perf_counter() - state["wall_time_s"]
    bar = tqdm(
        range(state["step"], config.steps),
        initial=state["step"],
        total=config.steps,
        desc=metadata.get("stage", "training"),
        disable=not progress or not accelerator.is_main_process,
        dynamic_ncols=True,
    )
    running = []
    processes, process = accelerator.num_processes, accelerator.process_index
    for step in bar:
        generator = step_generator(config.seed, 0, step)  # the step's global batch: the same on every process
        observation, actions, noise, time_ = _to(
            device, *draw_batch(policy, objective, train_data, config.batch_size, generator, processes, process)
        )
        if process:  # what the objective draws for its own rows: the first process's continues the step's generator
            generator = step_generator(config.seed, process, step)
        fraction_done = step / config.steps  # what scheduled objectives read
        running.append(
            train_step(
                module,
                optimizer,
                observation,
                actions,
                learning_rate=config.learning_rate_at(step),
                grad_clip=config.grad_clip,
                noise=noise,
                time=time_,
                generator=generator,
                progress=fraction_done,
                accelerator=accelerator,
            )
        )
        if average is not None:
            average.update(step)
        done = step + 1
        last = done == config.steps
        checkpointing = done % config.checkpoint_every == 0 or last
        # a row ends at each checkpoint too: no row spans a resume, so a resumed run logs the rows of an unbroken one
        if done % config.log_every == 0 or checkpointing:
            schedule = objective.schedule(fraction_done)
            state["history"].append(_history_row(accelerator, running, done, config.learning_rate_at(step), schedule))
            bar.set_postfix(loss=f"{state['history'][-1]['loss']:.4f}", refresh=False)
            running = []
        if val_data is not None and (done % config.validate_every == 0 or last):
            state["validation"].append(
                _validation_row(accelerator, module, val_data, config.batch_size, done, fraction_done)
            )
            bar.set_postfix(
                loss=f"{state['history'][-1]['loss']:.4f}" if state["history"] else "",
                val=f"{state['validation'][-1]['loss']:.4f}",
                refresh=False,
            )
        if checkpointing:
            checkpoint = save_run_checkpoint(
                accelerator, module, optimizer, average, state, done, started, run_directory, metadata, config
            )
            if checkpoint is not None and on_checkpoint is not None:
                on_checkpoint(checkpoint)
    bar.close()
    if accelerator.is_main_process:
        write_json(run_directory / HISTORY, state)
    return state


__all__ = ["HISTORY", "ChunkSource", "ObjectiveModule", "launch_state", "train", "train_step", "validation_loss"]
