"""Why does the daemon fly building C shorter than the benchmark? Fly the benchmark's runs of one building with one
part of the simulator changed at a time, so the gap can be pinned on a part (docs/runtime/README.md, session 33).

Each run is ``bench explore``'s run (same start pose, noise seed, end rule and planner loop); ``--variant`` swaps
the simulator's settings that ``run_episode`` builds:

* ``default``: the benchmark as shipped;
* ``no-sensor-noise``: the planar sensor's occupied-neighbour noise off (the daemon's depth camera has none);
* ``no-motion-noise``: the per-step pose noise off.

    python docs/runtime/session33/bench_variants.py --plan C --runs 10 --variant no-sensor-noise \
        --method drl+pred --out docs/runtime/session33/C_no-sensor-noise.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.sim.env import EnvConfig
from edge_explorer.vehicle.sensor import SensorConfig
from edge_explorer.world.catalog import load_buildings

VARIANTS = {
    "default": {},
    "no-sensor-noise": {"sensor": SensorConfig(occupied_noise_prob=0.0)},
    "no-motion-noise": {"motion_noise": False},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="C")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--variant", choices=sorted(VARIANTS), default="default")
    parser.add_argument("--method", default="drl+pred")
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    changes = VARIANTS[args.variant]
    original = bench.EnvConfig

    def patched(**kwargs: object) -> EnvConfig:
        return dataclasses.replace(original(**kwargs), **changes)

    bench.EnvConfig = patched  # run_episode builds its EnvConfig through this name
    raster = load_buildings(args.plan)[0]
    specs = bench.plan_specs(
        [raster], [args.method], args.runs, args.seed, predictor=args.predictor, policy=args.policy
    )
    records = [bench._run_task((raster, spec)) for spec in tqdm(specs, desc=f"{args.plan} {args.variant}")]
    paths = [r["path_at_coverage_m"] for r in records]
    summary = {
        "plan": args.plan,
        "variant": args.variant,
        "method": args.method,
        "paths_m": paths,
        "mean_m": float(np.mean([p for p in paths if p is not None])),
        "collisions": int(sum(r["collisions"] for r in records)),
        "curves": [{k: r["curves"][k] for k in ("coverage", "path_length_m")} for r in records],
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "curves"}))
    args.out.write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
