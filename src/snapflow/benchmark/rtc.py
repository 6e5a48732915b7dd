"""What real-time chunking buys at a chunk boundary, on recorded chunks of a LeRobot student.

For every frame of an episode past the first ``executed`` ones, the previous chunk is the one the student's
``teacher-10`` mode planned ``executed`` frames earlier (the same for every row, so rows compare); its unexecuted
part is what LeRobot's RTC engine passes as ``prev_chunk_left_over``, with ``inference_delay`` of those actions
executed while the new chunk is computed. Per row: how far the new chunk's first ``inference_delay`` actions are
from the leftover's (``prefix_error``; RTC's constraint) and how far the first action executed from the new chunk
is from the one the leftover would have executed (``boundary_jump``; what the robot feels), both L2 over the action
dimensions in the model's normalised units, and the batch-1 time of one chunk.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from snapflow.adapters.lerobot.rtc import padded_prefix, prefix_weights
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10
from snapflow.protocol import index_batch
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.tables import markdown_table


@dataclass(frozen=True)
class BoundaryRow:
    """One way of producing the next chunk, measured at its boundary with the previous one."""

    name: str
    mode: str
    rtc: str  # "off", "guided" (LeRobot's, per step), "inpaint" (the jump's), "guided-jump", "re-jump" (see ROWS),
    # "trained" / "trained-zeros" (a student distilled with known prefixes, given the previous chunk's, with or without
    # the schedule's ramp: TRAINED_ROWS)
    nfe: int
    prefix_error: float
    boundary_jump: float
    ms_per_chunk: float


# (name, sampling mode, RTC, NFE): what a user can run, then two jumps the policy does not offer: LeRobot's guidance
# applied to the jump as it is, and a second jump from the noise moved by the prefix gap
ROWS = (
    ("teacher 10-NFE", TEACHER_10.name, "off", 10),
    ("teacher 10-NFE + RTC", TEACHER_10.name, "guided", 10),
    ("SnapFlow 1-NFE", SNAPFLOW_1.name, "off", 1),
    ("SnapFlow 1-NFE + RTC (inpainted prefix)", SNAPFLOW_1.name, "inpaint", 1),
    ("SnapFlow 1-NFE + LeRobot's guidance as is (w = 10; not offered)", SNAPFLOW_1.name, "guided-jump", 1),
    (
        "SnapFlow 2-NFE: jump again from the noise moved by the gap, inpainted (not offered)",
        SNAPFLOW_1.name,
        "re-jump",
        2,
    ),
)


# the rows of a student distilled with known prefixes (``distill.rtc_max_delay`` > 0), in LeRobot's trained mode
TRAINED_ROWS = (
    ("SnapFlow 1-NFE trained for RTC: prefix given, the ramp inpainted", SNAPFLOW_1.name, "trained", 1),
    ("SnapFlow 1-NFE trained for RTC: prefix given, no ramp (ZEROS schedule)", SNAPFLOW_1.name, "trained-zeros", 1),
    ("the same student, 10-NFE trained for RTC: prefix given", TEACHER_10.name, "trained", 10),
)


def _chunk(student: Any, batch: dict[str, Any], noise: Tensor, mode: str, rtc: str, leftover: Any) -> Tensor:
    from lerobot.configs.types import RTCAttentionSchedule
    from lerobot.policies.rtc.configuration_rtc import RTCConfig
    from lerobot.policies.rtc.modeling_rtc import RTCProcessor

    student.config.sampling_mode = mode
    schedule = {"prefix_attention_schedule": RTCAttentionSchedule.ZEROS} if rtc == "trained-zeros" else {}
    enabled = RTCConfig(enabled=True, execution_horizon=leftover["horizon"], **schedule)
    student.config.rtc_config = enabled if rtc != "off" else None
    if rtc.startswith("trained"):
        student.config.rtc_config.mode = "trained"  # LeRobot's field where it has training-time RTC
    student.init_rtc_processor()
    kwargs = {key: leftover[key] for key in ("inference_delay", "prev_chunk_left_over")} if rtc != "off" else {}
    if rtc == "re-jump":  # the prefix gap moved into the noise, so the jump's own tail follows the prefix's mode
        first = _chunk(student, batch, noise, mode, "off", leftover)
        processor = RTCProcessor(RTCConfig(enabled=True, execution_horizon=leftover["horizon"]))
        weights = prefix_weights(
            processor,
            leftover["prev_chunk_left_over"],
            leftover["inference_delay"],
            leftover["horizon"],
            noise.shape[1],
        )
        gap = padded_prefix(leftover["prev_chunk_left_over"], noise) - torch.nn.functional.pad(
            first, (0, noise.shape[2] - first.shape[2])
        )
        return _chunk(student, batch, noise + weights * gap, mode, "inpaint", leftover)
    if rtc != "guided-jump":
        return student.predict_action_chunk(dict(batch), noise=noise, **kwargs)
    adapter = student.snapflow  # LeRobot's guidance formula on the jump velocity F(x_1, s=0, t=1), at its clamp
    context = adapter.encode(batch)
    ones = torch.ones(noise.shape[0])
    velocity = student.rtc_processor.denoise_step(
        noise, leftover["prev_chunk_left_over"], leftover["inference_delay"], 1.0,
        lambda x: adapter.velocity(x, ones, ones * 0, context), leftover["horizon"],
    )  # fmt: skip
    return (noise - velocity)[:, :, : student.config.action_feature.shape[0]]


def _batch_one_ms(student: Any, batch: dict[str, Any], noise: Tensor, mode: str, rtc: str, leftover: Any) -> float:
    """Median batch-1 time of one chunk over the first frames."""
    times = []
    for row in range(min(20, noise.shape[0])):
        one = {key: value[row : row + 1] for key, value in leftover.items() if isinstance(value, Tensor)}
        start = time.perf_counter()
        _chunk(student, index_batch(batch, slice(row, row + 1)), noise[row : row + 1], mode, rtc, {**leftover, **one})
        times.append(time.perf_counter() - start)
    return 1000 * sorted(times)[len(times) // 2]


@torch.no_grad()
def boundary_jumps(
    student: Any, batch: dict[str, Any], executed: int, inference_delay: int, seed: int = 0, trained: Any = None
) -> list[BoundaryRow]:
    """The rows of :data:`ROWS` for a LeRobot student (distilled, a SnapFlow student type) on ``batch``, the
    pre-processed frames of one episode in order, then those of :data:`TRAINED_ROWS` for ``trained``, a student of
    the same teacher distilled with known prefixes, on the same previous chunks and noise."""
    frames = next(value for value in batch.values() if isinstance(value, Tensor)).shape[0]
    chunk, dims = student.config.chunk_size, student.config.max_action_dim
    noise = torch.randn(frames, chunk, dims, generator=torch.Generator().manual_seed(seed))
    student.config.rtc_config = None
    student.init_rtc_processor()
    student.config.sampling_mode = TEACHER_10.name
    planned = student.predict_action_chunk(
        dict(batch), noise=torch.randn(noise.shape, generator=torch.Generator().manual_seed(seed + 1))
    )
    now = index_batch(batch, slice(executed, frames))
    leftover = {
        "prev_chunk_left_over": planned[: frames - executed, executed:],
        "inference_delay": inference_delay,
        "horizon": chunk - executed,
    }
    previous = padded_prefix(leftover["prev_chunk_left_over"], planned[executed:])
    rows = []
    measured = [(student, row) for row in ROWS] + ([(trained, row) for row in TRAINED_ROWS] if trained else [])
    for policy, (name, mode, rtc, nfe) in measured:
        actions = _chunk(policy, now, noise[executed:], mode, rtc, leftover)
        prefix = (actions[:, :inference_delay] - previous[:, :inference_delay]).norm(dim=-1).mean().item()
        jump = (actions[:, inference_delay] - previous[:, inference_delay]).norm(dim=-1).mean().item()
        milliseconds = _batch_one_ms(policy, now, noise[executed:], mode, rtc, leftover)
        rows.append(BoundaryRow(name, mode, rtc, nfe, prefix, jump, milliseconds))
    return rows


def write_boundary_report(rows: list[list[BoundaryRow]], settings: dict[str, Any], directory: str | Path) -> Path:
    """``rtc_boundary.json`` (the settings and each seed's rows) and ``rtc_boundary.md`` (the table: each row's mean
    over the seeds, the boundary jump with its 95% t-interval over them, its ratio to the guided teacher's) in
    ``directory``; ``rows`` holds one list of :func:`boundary_jumps` rows a seed, in the same order."""
    from snapflow.reporting.statistics import t_interval_95

    directory = Path(directory)
    write_json(
        directory / "rtc_boundary.json",
        {"settings": settings, "seeds": [[asdict(row) for row in seed_rows] for seed_rows in rows]},
    )
    guided = next(index for index, row in enumerate(rows[0]) if row.rtc == "guided")
    guided_jump = sum(seed_rows[guided].boundary_jump for seed_rows in rows) / len(rows)
    table = []
    for index, first in enumerate(rows[0]):
        jumps = [seed_rows[index].boundary_jump for seed_rows in rows]
        low, high = t_interval_95(jumps)
        mean = sum(jumps) / len(jumps)
        prefix = sum(seed_rows[index].prefix_error for seed_rows in rows) / len(rows)
        milliseconds = sorted(seed_rows[index].ms_per_chunk for seed_rows in rows)[len(rows) // 2]
        interval = f"{low:.3f}-{high:.3f}" if len(rows) > 1 else ""
        cells = (first.name, first.nfe, f"{prefix:.3f}", f"{mean:.3f}", interval, f"{mean / guided_jump:.2f}")
        table.append((*cells, f"{milliseconds:.1f}"))
    header = ["chunk from", "NFE", "prefix error", "boundary jump", "95% interval", "/ guided teacher"]
    text = markdown_table([*header, "ms / chunk (batch 1, CPU)"], table)
    seeds = f"{len(rows)} seed(s), each with its own teacher and students"
    write_text(directory / "rtc_boundary.md", f"{seeds}\n\n{text}\n")
    return directory


__all__ = ["BoundaryRow", "ROWS", "TRAINED_ROWS", "boundary_jumps", "write_boundary_report"]
