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
    rtc: str  # "off", "guided" (LeRobot's, per step), "inpaint" (the jump's), "guided-jump", "re-jump" (see ROWS)
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


def _chunk(student: Any, batch: dict[str, Any], noise: Tensor, mode: str, rtc: str, leftover: Any) -> Tensor:
    from lerobot.policies.rtc.configuration_rtc import RTCConfig
    from lerobot.policies.rtc.modeling_rtc import RTCProcessor

    student.config.sampling_mode = mode
    student.config.rtc_config = RTCConfig(enabled=True, execution_horizon=leftover["horizon"]) if rtc != "off" else None
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
    student: Any, batch: dict[str, Any], executed: int, inference_delay: int, seed: int = 0
) -> list[BoundaryRow]:
    """The rows of :data:`ROWS` for a LeRobot student (distilled, a SnapFlow student type) on ``batch``, the
    pre-processed frames of one episode in order."""
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
    for name, mode, rtc, nfe in ROWS:
        actions = _chunk(student, now, noise[executed:], mode, rtc, leftover)
        prefix = (actions[:, :inference_delay] - previous[:, :inference_delay]).norm(dim=-1).mean().item()
        jump = (actions[:, inference_delay] - previous[:, inference_delay]).norm(dim=-1).mean().item()
        milliseconds = _batch_one_ms(student, now, noise[executed:], mode, rtc, leftover)
        rows.append(BoundaryRow(name, mode, rtc, nfe, prefix, jump, milliseconds))
    return rows


def write_boundary_report(rows: list[BoundaryRow], settings: dict[str, Any], directory: str | Path) -> Path:
    """``rtc_boundary.json`` (the rows and the settings) and ``rtc_boundary.md`` (the table) in ``directory``."""
    directory = Path(directory)
    write_json(directory / "rtc_boundary.json", {"settings": settings, "rows": [asdict(row) for row in rows]})
    table = markdown_table(
        ["chunk from", "NFE", "prefix error", "boundary jump", "ms / chunk (batch 1, CPU)"],
        [
            (row.name, row.nfe, f"{row.prefix_error:.3f}", f"{row.boundary_jump:.3f}", f"{row.ms_per_chunk:.1f}")
            for row in rows
        ],
    )
    write_text(directory / "rtc_boundary.md", table + "\n")
    return directory


__all__ = ["BoundaryRow", "ROWS", "boundary_jumps", "write_boundary_report"]
