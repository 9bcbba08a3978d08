"""Figures of a ``branch_q.py`` collection: plans, branched decisions, and how a re-flown greedy choice and the
tried alternatives compare (mean, median, robust spread), written as JSON::

    python docs/policy/session28/branch_summary.py runs/s28/branchq --out docs/policy/session28/branch_summary.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows = [row for meta in sorted(args.folder.glob("block-*.json")) for row in json.loads(meta.read_text())]
    based = [row for row in rows if row["base"] is not None]
    reflown, best_alt, mean_alt = [], [], []
    for row in based:
        for point in row["points"]:
            greedy = point["paths"][0][0]
            if greedy is not None:
                reflown.append(greedy - row["base"])
            alts = [p for cell in point["paths"][1:] for p in cell if p is not None]
            if greedy is not None and alts:
                best_alt.append(min(alts) - greedy)
                mean_alt.append(float(np.mean(alts)) - greedy)
    reflown, best_alt, mean_alt = map(np.array, (reflown, best_alt, mean_alt))
    summary = {
        "plans": len(rows),
        "base_flights_reaching_both_95": len(based),
        "branched_decisions": sum(len(row["points"]) for row in based),
        "greedy_reflown_minus_base_m": {
            "n": len(reflown),
            "mean": float(reflown.mean()),
            "sd": float(reflown.std(ddof=1)),
            "mad_sd": float(1.4826 * np.median(np.abs(reflown - np.median(reflown)))),
            "percentiles_5_25_50_75_95": np.percentile(reflown, [5, 25, 50, 75, 95]).round(2).tolist(),
        },
        "best_alternative_minus_greedy_reflown_m": {
            "n": len(best_alt),
            "mean": float(best_alt.mean()),
            "median": float(np.median(best_alt)),
        },
        "mean_alternative_minus_greedy_reflown_m": {
            "mean": float(mean_alt.mean()),
            "median": float(np.median(mean_alt)),
        },
    }
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
