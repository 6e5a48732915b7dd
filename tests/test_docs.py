"""The documentation site builds as a user builds it, with warnings as errors (a broken link, a missing page or an
unresolved API reference fails it), and its command-line reference is written from the CLI's own parsers, with an
example of each command that the parser takes."""

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


def _cli_reference_hook():
    spec = importlib.util.spec_from_file_location("cli_reference", ROOT / "scripts" / "mkdocs_cli_reference.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    return hook


def test_the_cli_reference_holds_every_command_with_its_example_and_every_option():
    """Each command's section: what it does (its parser's description), its example and every option the parser
    takes (those every command takes once, at the top); no line of its code blocks wider than a phone."""
    import argparse

    from snapflow.cli import build_parser, command_parsers

    hook = _cli_reference_hook()
    page = hook.on_page_markdown(f"# Reference\n\n{hook.MARKER}\n", page=None)
    assert hook.MARKER not in page
    commands = command_parsers(build_parser())
    assert len(commands) >= 15
    assert list(hook.EXAMPLES) == list(commands)  # one example each, in --help's order
    sections = dict(re.findall(r"^## (.+?)\n(.*?)(?=^## |\Z)", page, re.M | re.S))
    common = sections[hook.COMMON]
    for name, command in commands.items():
        section = sections[f"snapflow {name}"]
        assert hook._sentence(hook._escaped(command.description)) in section, name
        assert hook.example_block(hook.EXAMPLES[name]) in section, name
        parsers = [command] + [
            sub
            for action in command._actions
            if isinstance(action, argparse._SubParsersAction)
            for sub in action.choices.values()
        ]
        for parser in parsers:
            for action in parser._actions:
                for option in action.option_strings if action.help != argparse.SUPPRESS else ():
                    assert f"`{option}" in section or f"`{option}" in common, f"snapflow {name} {option}"
    code = [line for block in re.findall(r"^```\w*\n(.*?)^```", page, re.M | re.S) for line in block.splitlines()]
    assert code and max(map(len, code)) <= hook.EXAMPLE_WIDTH + len(" \\")
    assert hook.on_page_markdown("# Another page\n", page=None) == "# Another page\n"


@pytest.mark.parametrize("name", list(_cli_reference_hook().EXAMPLES))
def test_each_cli_reference_example_is_a_command_snapflows_parser_takes(name):
    import shlex

    from snapflow.cli import build_parser, command_parsers

    words = shlex.split(_cli_reference_hook().EXAMPLES[name])
    assert words[:2] == ["snapflow", name]
    try:
        assert build_parser().parse_args(words[1:]).command == name
    except SystemExit:
        pytest.fail(f"snapflow's parser refuses the reference's example: {shlex.join(words)}")
    # each flag spelled out, as the options list names it (argparse would take an abbreviation too)
    command = command_parsers(build_parser())[name]
    known = {option for action in command._actions for option in action.option_strings}
    assert not [word for word in words if word.startswith("-") and word not in known]


def _reference_modules() -> list[str]:
    return re.findall(r"^::: ([\w.]+)", (ROOT / "docs" / "reference" / "api.md").read_text(), re.M)


def _imported(name: str):
    """The module, or None where it needs LeRobot (an optional extra) or the plugin distribution beside snapflow and
    this environment lacks it."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as error:
        if error.name in ("lerobot", "lerobot_policy_snapflow"):
            return None
        raise


def test_every_public_class_and_function_of_the_api_reference_has_a_docstring():
    """An undocumented public name fails: each class and function in the ``__all__`` of a module the reference
    renders, and each name ``snapflow`` itself exports."""
    import inspect

    import snapflow

    modules = [module for module in map(_imported, _reference_modules()) if module is not None]
    public = [(module.__name__, name, getattr(module, name)) for module in modules for name in module.__all__]
    public += [("snapflow", name, getattr(snapflow, name)) for name in snapflow.__all__]
    undocumented = [
        f"{module}.{name}"
        for module, name, value in public
        if (inspect.isclass(value) or inspect.isfunction(value)) and not inspect.getdoc(value)
    ]
    assert not undocumented


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The documentation site, built once a module as CI builds it (warnings are errors)."""
    if shutil.which("mkdocs") is None:
        pytest.skip("the docs extra is installed by the README's test command")
    site = tmp_path_factory.mktemp("docs") / "site"
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return site


def test_the_site_builds_with_warnings_as_errors(site):
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


def test_every_result_page_is_in_the_menu_or_linked_from_the_index_of_result_pages():
    """mkdocs does not list the pages inside the result folders as missing from the menu (``not_in_nav``), so this is
    what keeps each of them reachable: every Markdown page under ``docs/results/`` is in the menu or linked from
    ``docs/results/pages.md``, and every link there leads to a page."""
    results = ROOT / "docs" / "results"
    menu = {
        ROOT / "docs" / path
        for path in re.findall(r":\s*(results/\S+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    }
    index = results / "pages.md"
    assert index in menu
    linked = {(results / link).resolve() for link in re.findall(r"\]\(([^)#\s]+\.md)\)", index.read_text())}
    assert all(path.is_file() for path in linked), sorted(str(path) for path in linked if not path.is_file())
    unreachable = sorted(str(page.relative_to(results)) for page in results.rglob("*.md") if page not in menu | linked)
    assert not unreachable, f"neither in the menu nor linked from docs/results/pages.md: {unreachable}"


#: what a reader types, and the page the site's search must put first (a how-to before the results that cite it)
FIRST_RESULTS = {
    "distill pi0.5": "tutorials/distil-lerobot/",
    "distill smolvla": "tutorials/distil-lerobot/",
    "serve a student": "tutorials/serve/",
    "install": "install/",
}


@pytest.mark.skipif(shutil.which("chromium") is None, reason="Debian's chromium runs the site's search")
def test_the_site_search_puts_the_how_to_first(site):
    from tests.site_search import ranked_pages

    for query, first in FIRST_RESULTS.items():
        ranked = ranked_pages(site, query, shutil.which("chromium"))
        assert ranked[:1] == [first], (query, ranked[:5])
    assert "types/pi05/" in ranked_pages(site, "distill pi0.5", shutil.which("chromium"))[:3]
