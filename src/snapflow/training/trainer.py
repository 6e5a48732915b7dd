"""Training loop for teachers (flow matching) and students (SnapFlow), on Hugging Face Accelerate.

Everything random in step k (batch indices, noise, FM times, the one-step rows' times) comes from a generator seeded by
(seed, process, k), and the learning rate is a function of k, so ``resume`` continues the same loss curve.
Under ``accelerate launch`` each process draws its own batches and Accelerate averages the gradients. Where a run starts
(fresh or resumed) and each checkpoint it saves are :mod:`snapflow.training.resuming`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any, Protocol

import torch
from accelerate import Accelerator
from torch import Tensor, nn
from tqdm.auto import tqdm

from snapflow.objective.base import TwoBranchObjective
from snapflow.protocol import map_tensors
from snapflow.reporting.files import write_json
from snapflow.reporting.locks import hold_run_lock
from snapflow.training.config import TrainConfig
from snapflow.training.ema import WeightAverage
from snapflow.training.resuming import continue_from_kept, keeping_each_checkpoint, save_run_checkpoint, starting_state

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


def _step_generator(seed: int, process: int, step: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed * 1_000_003 + process * 7_919 + step)


def _draw(objective: TwoBranchObjective, data: ChunkSource, batch_size: int, generator: torch.Generator):
    indices = torch.randint(len(data), (batch_size,), generator=generator)
    observation, actions = data.batch(indices)
    noise = torch.randn(actions.shape, generator=generator)
    time = objective.time_sampler(objective.num_flow_matching(batch_size), generator=generator)
    return observation, actions, noise, time


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
        observation, actions, noise, time = _to(device, *_draw(module.objective, data, batch_size, generator))
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
) -> dict[str, Any]:
    """Optimise ``objective`` on ``policy`` (any module implementing FlowPolicy); checkpoints under
    ``run_directory/checkpoints``. The data needs ``len()`` and ``batch(indices) -> (observation, actions)``.

    ``trainable`` restricts the optimised parameters (a policy's ``expert_parameters()``: the action expert and
    phi_s); default: all.
    ``metadata`` is the policy description saved beside the weights (see ``policy_metadata``).
    Returns the trainer state (history of losses and validation). Holds the run folder for the whole run: another
    process training into it is refused with :class:`~snapflow.reporting.locks.RunLockedError`, which names
    ``holder`` (the command that trains, e.g. ``snapflow train``). ``on_checkpoint`` is called with each checkpoint
    once it is whole and marked latest (a sweep keeps a copy of it to commit).
    ``keep_progress``: a folder that holds a copy of the latest checkpoint, all that resuming reads (the previous copy
    removed), to commit or carry to another machine; with ``resume``, a run folder without a checkpoint of its own
    continues from the one kept there.
    """
    run_directory = Path(run_directory)
    accelerator = Accelerator(mixed_precision=config.mixed_precision)
    # only the main process writes the run, so only it holds the folder (the processes of one launch would otherwise
    # refuse each other)
    with hold_run_lock(run_directory, holder) if accelerator.is_main_process else nullcontext():
        if keep_progress is not None:
            if resume and accelerator.is_main_process:
                continue_from_kept(accelerator, run_directory, Path(keep_progress), config)
            accelerator.wait_for_everyone()
            on_checkpoint = keeping_each_checkpoint(Path(keep_progress), on_checkpoint)
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
        )


def _optimiser(
    policy: nn.Module, trainable: list[nn.Parameter] | None, config: TrainConfig
) -> tuple[torch.optim.AdamW, WeightAverage | None]:
    """AdamW over ``trainable`` (default: every parameter of ``policy``), every other parameter frozen, and the
    weight average of the trained parameters where ``config`` keeps one."""
    parameters = trainable if trainable is not None else list(policy.parameters())
    trainable_ids = {id(p) for p in parameters}
    for parameter in policy.parameters():
        parameter.requires_grad_(id(parameter) in trainable_ids)
    optimizer = torch.optim.AdamW(parameters, lr=config.learning_rate, weight_decay=config.weight_decay)
    if config.ema_decay is None:
        return optimizer, None
    trained = {name: p for name, p in policy.named_parameters() if id(p) in trainable_ids}
    return optimizer, WeightAverage(trained, config.ema_decay)


def _history_row(running: list[Tensor], step: int, learning_rate: float, schedule: dict[str, Any]) -> dict[str, Any]:
    """The mean [loss, FM loss, one-step loss] of the steps since the last row, logged at ``step``."""
    loss, flow_matching, consistency = torch.stack(running).float().mean(0).tolist()
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
) -> dict[str, Any]:
    """:func:`train` with the run folder held."""
    optimizer, average = _optimiser(policy, trainable, config)
    state = starting_state(accelerator, run_directory, policy, optimizer, average, config, resume)
    module, optimizer = accelerator.prepare(ObjectiveModule(policy, objective), optimizer)
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
    for step in bar:
        generator = _step_generator(config.seed, accelerator.process_index, step)
        observation, actions, noise, time_ = _to(device, *_draw(objective, train_data, config.batch_size, generator))
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
        if done % config.log_every == 0 or last:
            schedule = objective.schedule(fraction_done)
            state["history"].append(_history_row(running, done, config.learning_rate_at(step), schedule))
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
        if done % config.checkpoint_every == 0 or last:
            checkpoint = save_run_checkpoint(
                accelerator, module, optimizer, average, state, done, started, run_directory, metadata, config
            )
            if checkpoint is not None and on_checkpoint is not None:
                on_checkpoint(checkpoint)
    bar.close()
    if accelerator.is_main_process:
        write_json(run_directory / HISTORY, state)
    return state
