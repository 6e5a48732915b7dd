"""MkDocs hook: the command-line reference page written from the CLI's own parsers at build time, so it cannot drift
from them (``mkdocs.yml`` names it under ``hooks``)."""

from __future__ import annotations

from typing import Any

MARKER = "<!-- cli-reference -->"


def cli_reference() -> str:
    """Every ``snapflow`` command's help, in the order ``snapflow --help`` lists them, as Markdown."""
    from snapflow.cli import build_parser, command_parsers

    parser = build_parser()
    sections = [f"```text\n{parser.format_help()}```"]
    for name, command in command_parsers(parser).items():
        sections.append(f"## snapflow {name}\n\n```text\n{command.format_help()}```")
    return "\n\n".join(sections)


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    """Fill the reference page's marker; every other page is left as it is."""
    return markdown.replace(MARKER, cli_reference()) if MARKER in markdown else markdown
