"""What ``git status --porcelain`` lists for a checkout: the suite's record of the tree before and after it runs."""

from __future__ import annotations

import subprocess
from pathlib import Path

SOURCE_FOLDERS = ("edge_explorer/", "tests/")


def porcelain(root: Path) -> frozenset[str] | None:
    """The lines of ``git status --porcelain`` (untracked files one by one) for ``root``; None outside a checkout."""
    try:
        done = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=all"],
            capture_output=True,
            text=True,
            check=False,
        )
    except FileNotFoundError:
        return None
    if done.returncode != 0:
        return None
    return frozenset(line for line in done.stdout.splitlines() if line)


def new_entries(before: frozenset[str], after: frozenset[str]) -> list[str]:
    """The status lines present after and not before (what was written into the tree outside ignored folders).

    The source folders and Python files are left out: tests write data, reports, models, logs and profiles into
    the working directory or the data folders, never source, whereas in a checkout shared by several engineers
    someone edits source (modules, their configs) while the suite runs."""
    return sorted(line for line in after - before if not _is_source(line[3:].strip('"')))


def _is_source(path: str) -> bool:
    return path.endswith(".py") or path.startswith(SOURCE_FOLDERS)
