"""Two `bench explore` JSONs flown with the same seeds and starts, paired run by run (issue #17 / #21): per method,
the new path at 95 % coverage and at 95 % correct coverage minus the old (mean ± s.e.), runs with a collision, runs
that reached each goal; then the issue-#21 ratios inside the new file.

    python scripts/paired_vs.py NEW.json OLD.json
"""

import argparse
import json
from collections import defaultdict

import numpy as np


def load(path: str) -> dict[str, dict[tuple, dict]]:
    runs: dict[str, dict[tuple, dict]] = defaultdict(dict)
    for record in json.load(open(path))["runs"]:
        spec = record["spec"]
        runs[spec["method"]][(spec["plan"], spec["run"])] = record
    return runs


def paired(a: dict, b: dict, key: str) -> tuple[float, float, float, float, int, int]:
    keys = [k for k in a if k in b and a[k][key] is not None and b[k][key] is not None]
    x, y = np.array([a[k][key] for k in keys]), np.array([b[k][key] for k in keys])
    d = x - y
    return x.mean(), y.mean(), d.mean(), d.std(ddof=1) / np.sqrt(len(d)), int((d < 0).sum()), len(d)


def main(new_path: str, old_path: str) -> None:
    new, old = load(new_path), load(old_path)
    for method in (m for m in new if m in old):
        for key in ("path_at_coverage_m", "path_at_correct_coverage_m"):
            x, y, d, se, shorter, n = paired(new[method], old[method], key)
            figures = f"new {x:6.2f}  old {y:6.2f}  diff {d:+.2f} ± {se:.2f} m (shorter {shorter}/{n})"
            print(f"{method:18s} {key:27s} {figures}")
        for label, runs in (("new", new[method]), ("old", old[method])):
            collided = sum(1 for r in runs.values() if r["collisions"])
            reached = sum(1 for r in runs.values() if r["path_at_coverage_m"] is not None)
            correct = sum(1 for r in runs.values() if r["path_at_correct_coverage_m"] is not None)
            counts = f"{collided} runs with a collision, 95 % {reached}/{len(runs)}, 95 % correct {correct}"
            print(f"{'':18s} {label}: {counts}")
    for a, b in (("predfrontier+pred", "frontier+pred"), ("drl+pred", "frontier"), ("drl+pred", "predfrontier+pred")):
        if a in new and b in new:
            x, y, d, se, shorter, n = paired(new[a], new[b], "path_at_coverage_m")
            print(f"{a} / {b}: {x:.2f} / {y:.2f} = {x / y:.3f}; diff {d:+.2f} ± {se:.2f} m, shorter on {shorter}/{n}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", help="the new `bench explore` JSON")
    parser.add_argument("old", help="the old one, flown with the same seeds and starts")
    args = parser.parse_args()
    main(args.new, args.old)
