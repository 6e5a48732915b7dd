"""``snapflow checkpoints``: the checkpoints (and a sweep's packed demonstrations) kept in the repository's history
instead of its tree (:mod:`snapflow.reporting.archive`): list them, restore them where they were, archive new ones."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.cli.common import add_command
from snapflow.reporting.archive import (
    ARCHIVED_GLOBS,
    ARCHIVED_ROOT,
    MANIFEST,
    archive,
    is_present,
    pending,
    read_manifest,
    repository_root,
    restore,
    select,
)


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "checkpoints",
        f"checkpoints and packed demonstrations kept in git history, not the tree: list, restore, archive "
        f"(manifest: {MANIFEST})",
        run,
        _interrupted,
    )
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION", help="what to do")
    listing = actions.add_parser("list", help="each archived file, its size, and whether it is in place")
    listing.add_argument("paths", nargs="*", metavar="PATH", help="only the files at or under these paths")
    restoring = actions.add_parser("restore", help="write archived files back where they were, from history")
    restoring.add_argument(
        "paths", nargs="*", metavar="PATH", help="only the files at or under these paths (default: all)"
    )
    archiving = actions.add_parser(
        "archive",
        help=f"commit the {' and '.join(ARCHIVED_GLOBS)} files under {ARCHIVED_ROOT}/ not yet archived, then a commit that removes "
        "them from the tree and names the first in the manifest; the files stay on disk",
    )
    archiving.add_argument(
        "-m", "--message", default="Checkpoints archived", help="the first line of both commits' messages"
    )


def run(args: argparse.Namespace) -> int:
    root = repository_root()
    if args.action == "archive":
        paths = pending(root)
        if not paths:
            print(f"nothing to archive: every {' and '.join(ARCHIVED_GLOBS)} under {ARCHIVED_ROOT}/ is in {MANIFEST}")
            return 0
        done = archive(root, paths, args.message)
        print(f"archived {len(paths)} file(s) in commit {done.added[:12]}; out of the tree in {done.removed[:12]}")
        if done.superseded:
            gone = ", ".join(done.superseded)
            print(f"dropped from {MANIFEST}, their folders gone (their weights stay in history): {gone}")
        return 0
    entries = select(read_manifest(root), args.paths)
    if args.action == "list":
        for entry in entries:
            state = "in place" if is_present(root, entry) else "archived"
            print(f"{entry.path}  {entry.bytes / 1e6:.1f} MB  commit {entry.commit[:12]}  {state}")
        print(f"{len(entries)} file(s), {sum(entry.bytes for entry in entries) / 1e6:.1f} MB")
        return 0
    written = restore(root, entries)
    size = sum(entry.bytes for entry in written) / 1e6
    print(f"restored {len(written)} file(s) ({size:.1f} MB); {len(entries) - len(written)} already in place")
    return 0


def _interrupted(args: argparse.Namespace) -> str:
    return "interrupted; every file is written whole or not at all, and a commit is made whole or not at all"
