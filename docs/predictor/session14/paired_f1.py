"""Paired per-plan differences between two `eval predictor` JSONs (issue #17): F1 at each true-coverage level,
mean ± standard error over the plans both scored.

    python docs/predictor/session14/paired_f1.py NEW.json OLD.json [NEW2.json OLD2.json ...]
"""

import json
import sys

import numpy as np


def paired(new_path: str, old_path: str, key: str = "f1") -> str:
    new, old = json.load(open(new_path)), json.load(open(old_path))
    a = {p["plan"]: p["at"] for p in new["per_plan"]}
    b = {p["plan"]: p["at"] for p in old["per_plan"]}
    parts = []
    for level in new["levels"]:
        d = np.array([a[k][level][key] - b[k][level][key] for k in a if k in b and a[k].get(level) and b[k].get(level)])
        parts.append(f"{level}: {d.mean():+.4f} ± {d.std(ddof=1) / np.sqrt(len(d)):.4f} (n={len(d)})")
    return "; ".join(parts)


def main(paths: list[str]) -> None:
    for new_path, old_path in zip(paths[::2], paths[1::2], strict=True):
        print(f"{new_path} − {old_path}: F1 {paired(new_path, old_path)}")


if __name__ == "__main__":
    main(sys.argv[1:])
