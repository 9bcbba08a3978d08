"""Goal-demo shards from branch-credit records (``branch_credit.py``): a branched decision is labelled with the cell
whose flight was shortest at 95 % coverage — an alternative that beat the greedy flight by ``--margin`` metres, or
the greedy cell when it beat every alternative that flew by ``--margin`` — and left out otherwise (too close to call
from one flight each). Failed branches (no 95 %, or a collision) count as losing::

    python docs/policy/session27/labels.py runs/s27/branch/train --margin 1.5 --out runs/s27/branch/demos
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from edge_explorer.learn.goal_demos import write_demos


def label(base: float, greedy: int, cells: list[int], paths: list[float | None], margin: float) -> int | None:
    """The decision's label (see the module docstring), or None."""
    flown = [(p, c) for p, c in zip(paths, cells, strict=True) if p is not None]
    if flown and min(flown)[0] <= base - margin:
        return min(flown)[1]
    if cells and all(p is None or p >= base + margin for p in paths):
        return greedy
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--margin", type=float, default=1.5)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    counts = {"points": 0, "better": 0, "greedy": 0}
    gains = []
    for meta in sorted(args.folder.glob("block-*.json")):
        rows = json.loads(meta.read_text())
        with np.load(meta.with_suffix(".npz")) as data:
            arrays = {k: data[k] for k in data.files}
        records, k = [], 0
        for row in rows:
            for point in row["points"]:
                counts["points"] += 1
                cell = label(row["base"], point["greedy"], point["cells"], point["paths"], args.margin)
                flown = [p for p in point["paths"] if p is not None]
                if flown:
                    gains.append(row["base"] - min(flown))
                if cell is not None:
                    counts["better" if cell != point["greedy"] else "greedy"] += 1
                    records.append(
                        (arrays["high"][k], arrays["thres"][k], int(arrays["last"][k]), arrays["mask"][k], cell)
                    )
                k += 1
        if records:
            shard = args.out / f"shard-{meta.stem.split('-')[1]}"
            write_demos(shard.with_suffix(".npz"), records)
            shard.with_suffix(".json").write_text(json.dumps({"decisions": len(records)}))
    gains = np.array(gains)
    print(
        f"{counts['points']} branched decisions: best alternative shorter by ≥ {args.margin} m on {counts['better']}, "
        f"greedy best by ≥ {args.margin} m on {counts['greedy']}; best alternative − base: "
        f"median {-np.median(gains):+.2f} m, mean {-gains.mean():+.2f} m"
    )


if __name__ == "__main__":
    main()
