"""The product stands alone: no module or test cites the design doc or data outside the repository (docs/design.md
is the design; real floor plans beside a checkout are for validation and never needed)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = re.compile("DESIGN" + r"\.md|\.\./" + "shared")


def test_no_code_or_test_refers_outside_the_repository() -> None:
    files = [*sorted((ROOT / "edge_explorer").rglob("*.py")), *sorted((ROOT / "tests").rglob("*.py"))]
    hits = [
        f"{p.relative_to(ROOT)}:{n}"
        for p in files
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if OUTSIDE.search(line)
    ]
    assert len(files) > 100 and hits == []
