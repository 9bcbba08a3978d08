"""Average goal-policy weights ("model soup", Wortsman et al. 2022) of fine-tunes that share one starting point.

Session 26 (issue #21) tried it on the self-imitation fine-tunes of rounds 2 and 3, all started from the round-1
weights: the average keeps the format metadata (the network's widths) so every tool reads it as a policy::

    python docs/policy/session26/soup.py --out runs/s26/soup2.safetensors \\
        runs/s25/si/bcA/checkpoint.safetensors runs/s26/si/bcA/checkpoint.safetensors
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from safetensors import safe_open
from safetensors.numpy import load_file, save_file


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights", type=Path, nargs="+", help="goal-policy .safetensors files of the same network")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    metas = [safe_open(str(p), "np").metadata() for p in args.weights]
    if any(m != metas[0] for m in metas):
        print("error: the weights differ in network metadata; average only fine-tunes of one network", file=sys.stderr)
        return 2
    tensors = [load_file(str(p)) for p in args.weights]
    names = tensors[0].keys()
    soup = {n: np.mean([t[n] for t in tensors], axis=0).astype(tensors[0][n].dtype) for n in names}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_file(soup, str(args.out), metadata=metas[0])
    print(f"{len(tensors)} weights averaged -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
