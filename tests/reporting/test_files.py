"""A path as a result file records it: never an absolute path of the machine that wrote it."""

from __future__ import annotations

from pathlib import Path

import pytest

from snapflow.reporting.files import recorded_path


def test_a_path_inside_the_working_directory_is_recorded_relative_to_it(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert recorded_path(tmp_path / "outputs" / "student") == "outputs/student"
    assert recorded_path("outputs/student") == "outputs/student"


@pytest.mark.parametrize("elsewhere", ["/tmp/lat/compile-cache", "/work/outputs/libero2/student"])
def test_an_absolute_path_elsewhere_is_recorded_by_its_last_part(tmp_path: Path, monkeypatch, elsewhere) -> None:
    monkeypatch.chdir(tmp_path)
    assert recorded_path(elsewhere) == Path(elsewhere).name
