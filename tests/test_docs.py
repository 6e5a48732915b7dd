"""The documentation site builds as a user builds it, with warnings as errors (a broken link, a missing page or an
unresolved API reference fails it), and its command-line reference is the CLI's own help."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_cli_reference_holds_every_commands_help_as_the_parser_prints_it():
    from snapflow.cli import build_parser, command_parsers

    spec = importlib.util.spec_from_file_location("cli_reference", ROOT / "scripts" / "mkdocs_cli_reference.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    page = hook.on_page_markdown(f"# Reference\n\n{hook.MARKER}\n", page=None)
    assert hook.MARKER not in page
    commands = command_parsers(build_parser())
    assert len(commands) >= 15
    for name, command in commands.items():
        assert f"## snapflow {name}\n\n```text\n{command.format_help()}```" in page
    assert hook.on_page_markdown("# Another page\n", page=None) == "# Another page\n"


def _reference_modules() -> list[str]:
    return re.findall(r"^::: ([\w.]+)", (ROOT / "docs" / "reference" / "api.md").read_text(), re.M)


def test_every_public_class_and_function_of_the_api_reference_has_a_docstring():
    """An undocumented public name fails: each class and function in the ``__all__`` of a module the reference
    renders, and each name ``snapflow`` itself exports."""
    import importlib
    import inspect

    import snapflow

    modules = [importlib.import_module(name) for name in _reference_modules()]
    public = [(module.__name__, name, getattr(module, name)) for module in modules for name in module.__all__]
    public += [("snapflow", name, getattr(snapflow, name)) for name in snapflow.__all__]
    undocumented = [
        f"{module}.{name}"
        for module, name, value in public
        if (inspect.isclass(value) or inspect.isfunction(value)) and not inspect.getdoc(value)
    ]
    assert not undocumented


@pytest.mark.skipif(shutil.which("mkdocs") is None, reason="the docs extra is installed by the README's test command")
def test_the_site_builds_with_warnings_as_errors(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    site = tmp_path / "site"
    assert "snapflow distill" in (site / "reference" / "cli" / "index.html").read_text()
    api = (site / "reference" / "api" / "index.html").read_text()
    assert "FlowPolicy" in api
    assert not re.search(r":(class|func|meth|mod|data|attr):<code>", api), "a docstring's Sphinx role left as text"
    assert "<code>snapflow.nn.SnapFlowPolicy</code>" in api
    import snapflow

    for name in snapflow.__all__:  # everything the package exports has its entry, under a module the page renders
        assert any(f'id="{module}.{name}"' in api for module in _reference_modules()), name
    for page in ("guides/libero", "RESULTS", "ARCHITECTURE", "changelog"):
        assert (site / page / "index.html").exists()
