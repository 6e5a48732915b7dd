"""MkDocs hook: the command-line reference page written from the CLI's own parsers at build time, so it cannot drift
from them (``mkdocs.yml`` names it under ``hooks``).

Each command gets what it does (its parser's description), one example (:data:`EXAMPLES`, which
``tests/test_docs.py`` parses with snapflow's own parser) and its options as a definition list, whose text wraps at
any width: no line of the page is wider than a phone. The options every command takes are listed once, at the top.
"""

from __future__ import annotations

import argparse
import re
import shlex
from collections.abc import Collection
from typing import Any

MARKER = "<!-- cli-reference -->"

#: one real command per sub-command, in one place: the page shows them and tests/test_docs.py parses each
EXAMPLES = {
    "toy": "snapflow toy --method meanflow --output outputs/toy-meanflow",
    "toy-compare": "snapflow toy-compare --targets euler:2 euler:8 bootstrap:8 --seeds 0 1 2 --workers 2",
    "collect": "snapflow collect --tasks mt10 --episodes 30 --output data/mt10",
    "experts": "snapflow experts --env libero --tasks libero_spatial --episodes 50",
    "train": "snapflow train --data data/mt10 --output runs/teacher",
    "distill": "snapflow distill --teacher runs/teacher --data data/mt10 --output runs/student",
    "eval": "snapflow eval --policy runs/student --modes teacher-10,snapflow-1 --tasks mt10 --episodes 10",
    "diagnose": "snapflow diagnose --teacher runs/teacher --student runs/student --task peg-insert-side-v3",
    "bench": "snapflow bench --policy runs/student --device cuda --fast-path deploy",
    "export": "snapflow export --policy runs/student --format onnx --output onnx/",
    "serve": "snapflow serve --port 8080",
    "bench-targets": "snapflow bench-targets --teacher runs/teacher --data data/mt10 --targets euler:2 bootstrap:8",
    "sweep": "snapflow sweep configs/sweeps/mt10-state.toml --status",
    "checkpoints": "snapflow checkpoints restore docs/results/lerobot-smolvla-libero/kept",
    "demo": "snapflow demo --output outputs/demo",
}

#: the widest line of an example's code block: what a phone shows without scrolling sideways
EXAMPLE_WIDTH = 40
COMMON = "Options every command takes"


def example_block(command: str) -> str:
    """The example, one option (a flag and its values) per line where the whole is wider than a phone."""
    words = shlex.split(command)
    if len(command) <= EXAMPLE_WIDTH:
        return f"```bash\n{command}\n```"
    groups: list[list[str]] = [words[:2]]  # snapflow <command>
    for word in words[2:]:
        if word.startswith("-"):  # a flag starts a line
            groups.append([word])
        elif len(groups) == 1 and len(" ".join([*groups[0], word])) <= EXAMPLE_WIDTH:
            groups[0].append(word)  # a positional, on the command's line while that fits
        elif len(groups) == 1:
            groups.append([word])  # else on a line of its own
        else:  # a flag's value
            groups[-1].append(word)
    lines = [" ".join(shlex.quote(word) for word in group) for group in groups]
    return "```bash\n" + " \\\n  ".join(lines) + "\n```"


def _escaped(text: str) -> str:
    """Help text as Markdown: what would read as markup escaped, outside the `code spans` it already holds."""
    parts = re.split(r"(`[^`]*`)", text)
    for index in range(0, len(parts), 2):
        parts[index] = re.sub(r"([\\*\[\]_])", r"\\\1", parts[index]).replace("<", "&lt;").replace(">", "&gt;")
    return "".join(parts)


def _sentence(text: str) -> str:
    text = text.strip()
    return (text[:1].upper() + text[1:]).rstrip(".") + "."


def _visible(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [action for action in parser._actions if action.help != argparse.SUPPRESS]


def _term(action: argparse.Action) -> str:
    """An option's longest name with its value's placeholder, then its other names (choices are listed in its
    description instead)."""
    if not action.option_strings:
        name = action.metavar or action.dest
        return f"`{name} ...`" if action.nargs in ("+", "*") else f"`{name}`"
    value = ""
    if action.nargs != 0:
        value = action.metavar if isinstance(action.metavar, str) else action.dest.upper()
        value = f" {value}" + (f" [{value} ...]" if action.nargs in ("+", "*") else "")
    first, *others = sorted(action.option_strings, key=lambda option: not option.startswith("--"))
    aliases = f" (or {', '.join(f'`{option}`' for option in others)})" if others else ""
    return f"`{first}{value}`{aliases}"


def _definition(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """One option as a Markdown definition: its names, then its help (default included), choices and whether it
    is required."""
    text = _escaped(parser._get_formatter()._expand_help(action)) if action.help else ""
    if action.choices:
        text += "; one of " + ", ".join(f"`{choice}`" for choice in action.choices)
    if action.required and action.option_strings:
        text = f"**Required.** {text}"
    return f"{_term(action)}\n:   {text.strip()}"


def common_options(commands: dict[str, argparse.ArgumentParser]) -> list[tuple[str, ...]]:
    """The options every command takes with the same help: listed once, at the top of the page."""
    shared = None
    for command in commands.values():
        own = {(tuple(action.option_strings), action.help) for action in _visible(command) if action.option_strings}
        shared = own if shared is None else shared & own
    first = next(iter(commands.values()))
    return [
        tuple(action.option_strings)
        for action in _visible(first)
        if (tuple(action.option_strings), action.help) in shared
    ]


def options_list(parser: argparse.ArgumentParser, skip: Collection[tuple[str, ...]] = ()) -> str:
    """A parser's options as definition lists, one per argument group that holds any (its title above it where it
    is not argparse's own), and which of a required set of alternatives must be given."""
    blocks = []
    for group in parser._action_groups:
        actions = [
            action
            for action in group._group_actions
            if action.help != argparse.SUPPRESS and tuple(action.option_strings) not in skip
        ]
        if not actions:
            continue
        title = "" if group.title in ("positional arguments", "options") else f"**{_sentence(group.title)}**\n\n"
        blocks.append(title + "\n\n".join(_definition(parser, action) for action in actions))
    for exclusive in parser._mutually_exclusive_groups:
        if exclusive.required:
            names = " or ".join(f"`{action.option_strings[0]}`" for action in exclusive._group_actions)
            blocks.append(f"One of {names} is required.")
    return "\n\n".join(blocks)


def command_section(name: str, command: argparse.ArgumentParser, common: list[tuple[str, ...]]) -> str:
    """``## snapflow <name>``: what it does, its example, its options; a nested command's actions under H3s."""
    lines = [f"## snapflow {name}", _sentence(_escaped(command.description or "")), example_block(EXAMPLES[name])]
    lines += [options_list(command, common), f"And the [options every command takes](#{_slug(COMMON)})."]
    for action in command._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                lines.append(f"### snapflow {name} {sub_name}")
                lines.append(_sentence(_escaped(sub.description or _help_of(action, sub_name))))
                lines.append(options_list(sub, [("-h", "--help")]) or "No options.")
    return "\n\n".join(line for line in lines if line)


def _help_of(action: argparse._SubParsersAction, name: str) -> str:
    return next((choice.help or "" for choice in action._choices_actions if choice.dest == name), "")


def _slug(title: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")


def cli_reference() -> str:
    """Every ``snapflow`` command, in the order ``snapflow --help`` lists them, as Markdown."""
    from snapflow.cli import build_parser, command_parsers

    parser = build_parser()
    commands = command_parsers(parser)
    common = common_options(commands)
    listing = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    index = [f"- [`{name}`](#snapflow-{_slug(name)}): {_escaped(_help_of(listing, name))}" for name in commands]
    everywhere = "\n\n".join(
        _definition(next(iter(commands.values())), action)
        for action in _visible(next(iter(commands.values())))
        if tuple(action.option_strings) in common
    )
    top = [
        "`snapflow COMMAND [OPTIONS]`, or `snapflow --version`. The commands:",
        "\n".join(index),
        f"## {COMMON}",
        everywhere,
    ]
    return "\n\n".join(top + [command_section(name, command, common) for name, command in commands.items()])


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    """Fill the reference page's marker; every other page is left as it is."""
    return markdown.replace(MARKER, cli_reference()) if MARKER in markdown else markdown
