"""The runtime stays readable: no module in edge_explorer/runtime/ (its packages included) over 500 lines."""

from __future__ import annotations

from pathlib import Path

import edge_explorer.runtime

MAX_LINES = 500
RUNTIME = Path(edge_explorer.runtime.__file__).resolve().parent


def test_no_runtime_module_over_500_lines() -> None:
    sizes = {p.relative_to(RUNTIME).as_posix(): len(p.read_text().splitlines()) for p in RUNTIME.rglob("*.py")}
    assert len(sizes) > 10  # the daemon's and the link's packages are walked too
    too_long = {name: lines for name, lines in sizes.items() if lines > MAX_LINES}
    assert not too_long, f"split these runtime modules (over {MAX_LINES} lines): {too_long}"


def test_every_runtime_module_says_what_it_owns() -> None:
    missing = [p.name for p in RUNTIME.rglob("*.py") if p.name != "__init__.py" and not p.read_text().startswith('"""')]
    assert not missing, f"runtime modules without a module docstring: {missing}"
