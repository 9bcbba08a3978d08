"""How often can single flights fall within ±15 % of a benchmark average? (issue #21's daemon acceptance rule)

For each building of a `bench explore` JSON, each run is compared with the average of the *other* runs of the same
method (leave-one-out: a new flight against a bench it is not part of), and the normal model with the runs'
coefficient of variation gives the expected count and the chance that all of a given number of flights pass.

    python scripts/within15.py docs/bench/policy_bundled.json drl+pred --flights 5
"""

import argparse
import json
from collections import defaultdict
from statistics import NormalDist

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bench_json")
    parser.add_argument("method")
    parser.add_argument("--flights", type=int, default=5, help="acceptance flights per building")
    parser.add_argument("--band", type=float, default=0.15)
    args = parser.parse_args()
    paths: dict[str, list[float]] = defaultdict(list)
    for record in json.load(open(args.bench_json))["runs"]:
        if record["spec"]["method"] == args.method and record["path_at_coverage_m"] is not None:
            paths[record["spec"]["plan"]].append(record["path_at_coverage_m"])
    normal = NormalDist()
    all_pass, expected_total, loo_total, runs_total = 1.0, 0.0, 0, 0
    for plan, values in sorted(paths.items()):
        x = np.array(values)
        loo = np.array([(x.sum() - v) / (len(x) - 1) for v in x])
        within = int((np.abs(x / loo - 1) <= args.band).sum())
        cv = x.std(ddof=1) / x.mean()
        p = 2 * normal.cdf(args.band / cv) - 1
        all_pass *= p**args.flights
        expected_total += p * args.flights
        loo_total, runs_total = loo_total + within, runs_total + len(x)
        print(
            f"{plan}: {len(x)} runs, mean {x.mean():.1f} m, CV {cv:.3f}; leave-one-out within ±{args.band:.0%}: "
            f"{within}/{len(x)}; normal model: P(one flight within) {p:.2f}"
        )
    n = args.flights * len(paths)
    print(
        f"all: leave-one-out {loo_total}/{runs_total}; normal model, {n} unbiased flights: expected "
        f"{expected_total:.1f}/{n} within, P(all {n} within) {all_pass:.3g}"
    )


if __name__ == "__main__":
    main()
