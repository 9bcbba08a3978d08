"""Choose the map stop rule's threshold on val (issue #56): the sweep behind
:data:`edge_explorer.predict.verification.DEFAULT_STOP_THRESHOLD_M2`.

Flies the benchmark's runs (``bench explore``'s start pose, noise seed, 1500-step cap) on generated val plans with
``--stop map`` and a threshold of 0 m² — the rule never fires, so each run goes on until its planner has nothing
left — recording the unverified area at every step. A run stopped by the rule at threshold T is the same run cut at
the first step whose unverified area is below T (the rule reads the maps and draws no random numbers), so one set of
flights answers every threshold: per method and T, the false stops (correct coverage < 90 % at the stop), correct
coverage and path at the stop, and the path at the stop minus Nearest Frontier's own end (same T), paired by plan::

    python scripts/stop_threshold_sweep.py --first 0 --count 20 --methods frontier,frontier+pred,drl+pred

Records go to ``runs/stop_sweep/`` (a rerun reuses them), the table to stdout and ``runs/stop_sweep/sweep.json``.
Tune on val plans only: the test split, A-D and the real plans are the acceptance.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.sim.runs import FALSE_STOP_CORRECT
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import DEFAULT_SEED, generate_checked

THRESHOLDS_M2 = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0)


def cut(record: dict[str, Any], threshold_m2: float) -> tuple[float, float]:
    """(correct coverage, path m) where the rule with ``threshold_m2`` would have stopped ``record``."""
    curves = record["curves"]
    hits = np.flatnonzero(np.asarray(curves["unverified_m2"]) < threshold_m2)
    k = int(hits[0]) if len(hits) else len(curves["path_length_m"]) - 1
    return float(curves["correct_coverage"][k]), float(curves["path_length_m"][k])


def sweep(records: list[dict[str, Any]], methods: list[str]) -> list[dict[str, Any]]:
    rows = []
    for t in THRESHOLDS_M2:
        stops = {m: {r["spec"]["plan"]: cut(r, t) for r in records if r["spec"]["method"] == m} for m in methods}
        ref = stops.get("frontier")
        for m in methods:
            correct = np.array([c for c, _ in stops[m].values()])
            paths = np.array([p for _, p in stops[m].values()])
            row = {
                "threshold_m2": t,
                "method": m,
                "runs": len(correct),
                "false_stops": int((correct < FALSE_STOP_CORRECT).sum()),
                "correct_at_stop_avg": float(correct.mean()),
                "correct_at_stop_min": float(correct.min()),
                "path_at_stop_avg_m": float(paths.mean()),
            }
            if ref is not None:
                d = np.array([stops[m][p][1] - ref[p][1] for p in stops[m] if p in ref])
                row["minus_frontier_end_m"] = float(d.mean())
                row["minus_frontier_end_se_m"] = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else None
            rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--first", type=int, default=0, help="first val plan index")
    parser.add_argument("--count", type=int, default=20, help="val plans")
    parser.add_argument("--methods", default="frontier,frontier+pred,drl+pred")
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out-dir", type=Path, default=Path("runs/stop_sweep"))
    args = parser.parse_args()
    methods = bench.parse_methods(args.methods)
    rasters = [
        plan_to_raster(generate_checked(DEFAULT_SEED, "val", k)) for k in range(args.first, args.first + args.count)
    ]
    config = bench.BenchConfig(stop="map", stop_threshold_m2=0.0)
    specs = bench.plan_specs(rasters, methods, 1, 0, config, args.predictor, args.policy)
    records = bench.run_benchmark(
        rasters, specs, args.workers, args.out_dir, lambda it, n: tqdm(it, total=n, desc="sweep", unit="run")
    )
    rows = sweep(records, methods)
    print("| T (m²) | method | false stops | correct at stop avg (min) | path at stop (m) | − frontier's end (m) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        se = r.get("minus_frontier_end_se_m")
        vs = "–" if "minus_frontier_end_m" not in r else f"{r['minus_frontier_end_m']:+.1f} ± {se or 0:.1f}"
        print(
            f"| {r['threshold_m2']:g} | {r['method']} | {r['false_stops']}/{r['runs']} | "
            f"{100 * r['correct_at_stop_avg']:.1f} % ({100 * r['correct_at_stop_min']:.1f} %) | "
            f"{r['path_at_stop_avg_m']:.1f} | {vs} |"
        )
    out = {"first": args.first, "count": args.count, "methods": methods, "rows": rows}
    (args.out_dir / "sweep.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
