"""A finished sweep's results: ``results.json``, one PNG per table, ``tables.md``, and the tables' blocks between
markers in a results document such as ``docs/results/metaworld.md`` (rows in :mod:`~snapflow.jobs.sweep.aggregate`, Markdown in
:mod:`~snapflow.jobs.sweep.markdown`, figures in :mod:`~snapflow.jobs.sweep.plots`)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

from snapflow.jobs.sweep.aggregate import TableResult, table_results
from snapflow.jobs.sweep.markdown import markdown_blocks, replace_block, tables_markdown
from snapflow.jobs.sweep.plots import plot_table
from snapflow.jobs.sweep.specs import SweepConfig
from snapflow.reporting.files import write_json, write_text


def write_results(
    config: SweepConfig, document: str | Path | None = None, tables: list[str] | None = None
) -> dict[str, Any]:
    """``results.json``, ``tables.md`` and one PNG per table in the sweep's results_dir; the tables also go
    into ``document`` (between their markers) if given. Returns the content of ``results.json``.

    ``tables``: rebuild only these from their evaluations; every other table is read back from the results.json
    already there and kept as it is, or left out if it has none yet (a sweep whose tables finish sessions apart).
    Raises FileNotFoundError naming the first evaluation not done when a rebuilt table has not run to the end.
    """
    rebuilt = config.table_names(tables)
    stored = config.results_dir / "results.json"
    earlier = json.loads(stored.read_text())["tables"] if stored.is_file() and len(rebuilt) < len(config.tables) else {}
    results = {
        table.name: table_results(config, table)
        if table.name in rebuilt
        else TableResult.from_dict(earlier[table.name])
        for table in config.tables
        if table.name in rebuilt or table.name in earlier
    }
    for name in rebuilt:
        plot_table(results[name], config.results_dir / f"{name}.png", config.title)
    summary = {
        "sweep": config.name,
        "title": config.title,
        "config": config.source.as_posix(),
        "data": asdict(config.data),
        "tables": {name: result.to_dict() for name, result in results.items()},
    }
    write_json(config.results_dir / "results.json", summary)
    write_text(config.results_dir / "tables.md", tables_markdown(config, results))
    if document is not None:
        document = Path(document)
        text = document.read_text() if document.is_file() else "# Results\n"
        for key, body in markdown_blocks(config, results, document.parent).items():
            text = replace_block(text, key, body)
        write_text(document, text)
    return summary


__all__ = ["write_results"]
