"""Reporting utilities every layer may use and that use no other part of snapflow: files written whole or not at
all, Markdown tables, PNG figures, the machine behind a figure, and summary statistics."""

from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import atomic_write, write_json, write_text
from snapflow.reporting.machine import machine, machine_description
from snapflow.reporting.statistics import mean_std
from snapflow.reporting.tables import markdown_table

__all__ = [
    "atomic_write",
    "write_json",
    "write_text",
    "markdown_table",
    "pyplot",
    "save_figure",
    "machine",
    "machine_description",
    "mean_std",
]
