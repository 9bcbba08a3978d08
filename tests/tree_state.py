"""What ``git status --porcelain`` lists for a checkout: the suite's record of the tree before and after it runs."""

from __future__ import annotations

import subprocess
from pathlib import Path


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

    Python source is left out: tests write data, reports, models, logs and profiles, never ``.py`` files, whereas in
    a checkout shared by several engineers someone edits source while the suite runs."""
    return sorted(line for line in after - before if not line.rstrip('"').endswith(".py"))
