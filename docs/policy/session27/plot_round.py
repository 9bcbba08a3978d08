"""Session 27's branch-credit candidates against the shipped policy (round 1), paired plan by plan per val set.

Writes ``candidates.png`` and ``candidates.json`` next to this script (the pairing is session 26's
``plot_candidates.paired_m``), plus the pooled figure over the three val sets::

    python docs/policy/session27/plot_round.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DOCS = HERE.parent
sys.path.insert(0, str(DOCS / "session26"))
from plot_candidates import BASE, paired_m, plot_rows  # noqa: E402

CANDIDATES = {
    "C1: branch labels only (352)": {"40–135": "session27/s27_C1.json"},
    "C2: branch labels + round 1's data": {
        "40–135": "session27/s27_C2.json",
        "136–231": "session27/s27_C2_b.json",
        "232–327": "session27/s27_C2_c.json",
    },
}


def pooled_m(sets: dict[str, str]) -> tuple[float, float, int]:
    """(mean, standard error, plans) of candidate − round 1 over every val set the candidate flew."""
    d = []
    for val, f in sets.items():
        a, b = ({r[0]: r[1] for r in json.loads((DOCS / p).read_text())["runs"]} for p in (f, BASE[val]))
        d += [a[k] - b[k] for k in a if k in b and a[k] is not None and b[k] is not None]
    d = np.array(d)
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d))), len(d)


def main() -> None:
    keys = ("mean_m", "se_m", "plans")
    rows = [
        {"candidate": name, "val": val, **dict(zip(keys, paired_m(DOCS / f, DOCS / BASE[val]), strict=True))}
        for name, sets in CANDIDATES.items()
        for val, f in sets.items()
    ]
    rows += [
        {"candidate": name, "val": "pooled", **dict(zip(keys, pooled_m(sets), strict=True))}
        for name, sets in CANDIDATES.items()
        if len(sets) > 1
    ]
    plot_rows(rows, "Per-decision branch credit (one rollout per goal) vs the shipped round 1", HERE, (9, 3.5))
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
