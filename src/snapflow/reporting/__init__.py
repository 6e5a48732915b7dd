"""Reporting utilities every layer may use and that use no other part of snapflow: files written whole or not at
all, the one-writer lock of a run folder, settings as records keep them, Markdown tables, PNG figures, the machine behind
a figure, and summary statistics."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.reporting.files": ["atomic_write", "write_json", "write_text"],
        "snapflow.reporting.locks": ["RunLockedError", "hold_run_lock"],
        "snapflow.reporting.records": ["added_option", "as_record"],
        "snapflow.reporting.tables": ["markdown_table"],
        "snapflow.reporting.figures": ["pyplot", "save_figure"],
        "snapflow.reporting.machine": ["machine", "machine_description"],
        "snapflow.reporting.statistics": ["mean_std", "wilson_interval", "paired_difference"],
    },
)
