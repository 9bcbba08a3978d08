"""Pool paired `expert_sweep.py` comparisons over several val blocks (session 37): mean ± s.e. of A − B over every
plan both sweeps reached 95 % on, with how many were shorter.

    python docs/policy/session37/pooled.py s37_decay1.0_40:s30_unseen0.25_40 s37_decay1.0_136:s30_unseen0.25_136 ...
"""

import json
import sys
from pathlib import Path

import numpy as np


def diffs(name_a: str, name_b: str) -> list[float]:
    a, b = (
        {r[0]: r for r in json.loads(Path(f"runs/expert_sweep/{n}.json").read_text())["runs"]} for n in (name_a, name_b)
    )
    return [a[p][1] - b[p][1] for p in a if p in b and a[p][1] is not None and b[p][1] is not None]


def main(pairs: list[str]) -> None:
    d = np.array([x for pair in pairs for x in diffs(*pair.split(":"))])
    print(
        f"pooled over {len(d)} plans: {d.mean():+.2f} ± {d.std(ddof=1) / np.sqrt(len(d)):.2f} m, "
        f"shorter on {(d < 0).sum()}, longer on {(d > 0).sum()}"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
