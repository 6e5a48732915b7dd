"""A diagnosis (:mod:`snapflow.evaluation.diagnosis`) as files: its JSON, a Markdown summary, the deviation by phase
and the chunks at the failed moments as figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from snapflow.evaluation.diagnosis import ChunkComparison, Diagnosis
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.tables import markdown_table


def plot_phases(diagnosis: Diagnosis, path: Path) -> Path:
    """Mean distance to the expert's action by episode phase, per row: failed episodes solid, successful dashed."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(7, 3.8))
    for index, row in enumerate(diagnosis.rows):
        color = f"C{index}"
        for values, style, kind in (
            (row.deviation_failed, "-", "failed"),
            (row.deviation_succeeded, "--", "succeeded"),
        ):
            points = [(p * diagnosis.phase_steps, v) for p, v in enumerate(values) if v is not None]
            if points:
                axis.plot(
                    *zip(*points, strict=True),
                    style,
                    color=color,
                    marker="o",
                    markersize=3,
                    label=f"{row.label} ({kind}; {row.successes}/{row.episodes} succeed)",
                )
    if diagnosis.failing_phase is not None:
        start = diagnosis.failing_phase * diagnosis.phase_steps
        axis.axvspan(start, start + diagnosis.phase_steps, color="0.9", zorder=0, label="failing phase")
    axis.set_xlabel("environment step (start of the phase)")
    axis.set_ylabel("|action - expert action|")
    axis.set_title(f"{diagnosis.task}: distance to the scripted expert along the episode", fontsize=10)
    axis.legend(fontsize=7)
    figure.tight_layout()
    return save_figure(figure, path)


ACTION_NAMES = ("x", "y", "z", "gripper")


def plot_chunks(diagnosis: Diagnosis, comparison: ChunkComparison, path: Path) -> Path:
    """Each row's chunk draws per action dimension at one failed moment, the nearest demonstration's chunk in black
    and the expert's action at the state as a star."""
    plt = pyplot()
    dims = len(comparison.expert_action)
    figure, axes = plt.subplots(1, dims, figsize=(3.2 * dims, 3.2), squeeze=False)
    for dim, axis in enumerate(axes[0]):
        for index, (label, chunks) in enumerate(comparison.chunks.items()):
            values = np.asarray(chunks)[:, :, dim]
            for draw, line in enumerate(values):
                axis.plot(line, color=f"C{index}", alpha=0.5, linewidth=1, label=label if draw == 0 else None)
        axis.plot(
            np.asarray(comparison.demonstration_chunk)[:, dim],
            color="black",
            linewidth=2,
            label="nearest demonstration",
        )
        axis.plot([0], [comparison.expert_action[dim]], "k*", markersize=10, label="expert at the state")
        axis.set_title(ACTION_NAMES[dim] if dim < len(ACTION_NAMES) else f"action {dim}", fontsize=9)
        axis.set_xlabel("chunk step")
    axes[0][0].legend(fontsize=6)
    figure.suptitle(
        f"{diagnosis.task}, evaluation episode {comparison.variation}, step {comparison.step}: predicted chunks",
        fontsize=10,
    )
    figure.tight_layout()
    return save_figure(figure, path)


def markdown_diagnosis(diagnosis: Diagnosis) -> str:
    """The rows' success and distance to the expert, and the chunk comparison at each failed moment."""
    lines = [
        f"# {diagnosis.task}: where the one-step policy fails",
        "",
        f"{diagnosis.benchmark}, {diagnosis.episodes} evaluation episodes, n_act {diagnosis.n_act}. Distance to the "
        "expert: Euclidean distance between the executed action and the scripted expert's action at the same state.",
        "",
        markdown_table(
            ["row", "mode", "successes", "mean distance to the expert"],
            [[r.label, r.mode, f"{r.successes} / {r.episodes}", f"{r.mean_deviation:.3f}"] for r in diagnosis.rows],
        ),
        "",
    ]
    if diagnosis.failing_phase is None:
        lines.append(f"{diagnosis.rows[-1].label} fails no episode.")
        return "\n".join(lines) + "\n"
    start = diagnosis.failing_phase * diagnosis.phase_steps
    lines += [f"Failing phase of {diagnosis.rows[-1].label}: steps {start}-{start + diagnosis.phase_steps - 1}.", ""]
    for comparison in diagnosis.comparisons:
        lines += [
            f"## Episode {comparison.variation}, step {comparison.step} (nearest demonstration state at "
            f"{comparison.demonstration_distance:.3f})",
            "",
            markdown_table(
                ["row", "MSE to the demonstration's chunk", "spread across draws", "first action to the expert"],
                [
                    [
                        label,
                        f"{comparison.error_to_demonstration[label]:.4f}",
                        f"{comparison.spread[label]:.4f}",
                        f"{comparison.first_action_to_expert[label]:.3f}",
                    ]
                    for label in comparison.chunks
                ],
            ),
            "",
        ]
    return "\n".join(lines) + "\n"


def write_diagnosis(diagnosis: Diagnosis, output: str | Path) -> list[Path]:
    """``diagnosis.json``, ``diagnosis.md``, ``phases.png`` and one ``chunks-<i>.png`` per compared moment."""
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    write_json(output / "diagnosis.json", diagnosis.to_dict())
    write_text(output / "diagnosis.md", markdown_diagnosis(diagnosis))
    paths = [plot_phases(diagnosis, output / "phases.png")]
    paths += [plot_chunks(diagnosis, c, output / f"chunks-{i}.png") for i, c in enumerate(diagnosis.comparisons)]
    return paths


__all__ = ["plot_phases", "plot_chunks", "markdown_diagnosis", "write_diagnosis"]
