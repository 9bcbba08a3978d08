"""Session 26's candidates against the shipped policy (round 1), paired plan by plan on the val sets they flew.

Reads the sweep files kept in docs/policy/session2{4,5,6}/ and writes ``candidates.png`` and ``candidates.json``
next to this script: mean ± standard error of (candidate − round 1) path at 95 % coverage, per val set::

    python docs/policy/session26/plot_candidates.py
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
DOCS = HERE.parent
BASE = {"40–135": "session24/s24_si_last.json", "136–231": "session24/s24_si_last_b.json",
        "232–327": "session24/s24_si_last_c.json"}  # fmt: skip
CANDIDATES = {
    "2A: round 2 only": {"40–135": "session25/s25_si2A.json"},
    "2B: rounds 1 + 2": {"40–135": "session25/s25_si2B.json"},
    "3A: round 3, lr 2e-4": {"40–135": "session26/s26_si3A.json"},
    "3B: round 3, lr 1e-4": {"40–135": "session26/s26_si3B.json"},
    "soup of 2A, 2B, 3A, 3B": {"40–135": "session26/s26_soup4.json"},
    "soup of 2A, 3A": {
        "40–135": "session26/s26_soup2.json",
        "136–231": "session26/s26_soup2_b.json",
        "232–327": "session26/s26_soup2_c.json",
    },
}


def paired_m(candidate: Path, base: Path) -> tuple[float, float, int]:
    """(mean, standard error, plans) of candidate − base path at 95 % over the plans both reached it on."""
    a, b = ({r[0]: r[1] for r in json.loads(p.read_text())["runs"]} for p in (candidate, base))
    d = np.array([a[k] - b[k] for k in a if k in b and a[k] is not None and b[k] is not None])
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d))), len(d)


def plot_rows(rows: list[dict], title: str, folder: Path, size: tuple[float, float]) -> None:
    """``candidates.json`` and ``candidates.png`` in ``folder``: one paired mean ± s.e. per row."""
    (folder / "candidates.json").write_text(json.dumps(rows, indent=1) + "\n")
    fig, ax = plt.subplots(figsize=size)
    for y, row in enumerate(rows):
        ax.errorbar(row["mean_m"], y, xerr=row["se_m"], fmt="o", capsize=3)
    ax.set_yticks(range(len(rows)), [f"{r['candidate']} (val {r['val']})" for r in rows], fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.invert_yaxis()
    ax.set(xlabel="candidate − shipped round 1: path at 95 % coverage (m, paired mean ± s.e.)", title=title)
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    fig.savefig(folder / "candidates.png", dpi=120)


def main() -> None:
    rows = [
        {
            "candidate": name,
            "val": val,
            **dict(zip(("mean_m", "se_m", "plans"), paired_m(DOCS / f, DOCS / BASE[val]), strict=True)),
        }
        for name, sets in CANDIDATES.items()
        for val, f in sets.items()
    ]
    plot_rows(rows, "Self-imitation rounds 2–3 and weight averages vs the shipped round 1", HERE, (9, 4.5))
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
