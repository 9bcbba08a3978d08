"""How much of a branch's difference is the choice and how much the noise (issue #21, session 27).

``branch_credit.py`` credits a decision by one flight per tried goal. This probe re-flies, at one early decision of
the base flight per plan, the greedy cell and ``--alternatives`` others ``--reseeds`` times each, with the
simulator's noise generator reseeded at that decision (the flight up to it is the base flight's, so only the noise
after it differs). The spread over reseeds of one cell is the rollout noise; the spread of the cells' means is what
a choice is worth::

    python docs/policy/session27/noise_probe.py --first 4000 --count 16 --out runs/s27/noise_probe.json
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
from multiprocessing import Pool
from pathlib import Path

import branch_credit as bc
import numpy as np
from tqdm import tqdm

from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans
from edge_explorer.world.plan import FloorPlan


class ReseedingPlanner(bc.BranchingPlanner):
    """:class:`branch_credit.BranchingPlanner` that also reseeds the simulator's noise at the branched decision."""

    def __init__(self, *args, reseed: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reseed = reseed

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if self.decisions == self.branch_at and self.env is not None:
            self.env.np_random = np.random.default_rng(self.reseed)
        return super().select_goal(view, pose)


def probe(indexed: tuple[int, FloorPlan]) -> dict:
    index, plan = indexed
    args = bc._WORKER["args"]
    raster = plan_to_raster(plan)
    base, planner = bc._flight(raster, record=True)
    early = [k for k, rec in enumerate(planner.records) if rec["coverage"] < 0.95]
    if base is None or not early:
        return {"plan": raster.name, "base": base, "cells": {}}
    k = int(np.random.default_rng([args.seed, index]).choice(early))
    rec = planner.records[k]
    cells = [rec["cell"], *bc.alternatives(rec["scores"], rec["cell"], args.alternatives, args.spacing)]
    paths: dict[str, list] = {}
    for cell in cells:
        paths[str(cell)] = []
        for r in range(args.reseeds):
            reseed = int(np.random.SeedSequence([args.seed, index, r]).generate_state(1)[0])
            planner_cls = functools.partial(ReseedingPlanner, reseed=reseed)
            paths[str(cell)].append(bc._flight(raster, k, cell, planner_cls=planner_cls)[0])
    return {"plan": raster.name, "base": base, "decision": k, "greedy": rec["cell"], "cells": paths}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, required=True)
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--alternatives", type=int, default=2)
    parser.add_argument("--reseeds", type=int, default=4)
    parser.add_argument("--spacing", type=int, default=3)
    bc.add_flight_args(parser)
    args = parser.parse_args()
    shards = sorted(args.plans.glob("*.jsonl.gz"))
    plans = itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)
    with Pool(args.workers, initializer=bc._init, initargs=(args,)) as pool:
        rows = list(tqdm(pool.imap(probe, enumerate(plans, start=args.first)), total=args.count, desc="noise probe"))
    within, between = [], []
    for row in rows:
        means = []
        for flights in row["cells"].values():
            ok = [p for p in flights if p is not None]
            if len(ok) >= 2:
                within.append(np.std(ok, ddof=1))
                means.append(np.mean(ok))
        if len(means) >= 2:
            between.append(np.std(means, ddof=1))
    summary = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "rollout_noise_sd_m": float(np.sqrt(np.mean(np.square(within)))) if within else None,
        "sd_of_cell_means_m": float(np.sqrt(np.mean(np.square(between)))) if between else None,
        "rows": rows,
    }
    args.out.write_text(json.dumps(summary, indent=1))
    print(
        f"{len(rows)} plans: rollout noise s.d. {summary['rollout_noise_sd_m']} m (one cell, reseeded), "
        f"s.d. of the cells' means {summary['sd_of_cell_means_m']} m (over {args.reseeds} reseeds)"
    )


if __name__ == "__main__":
    main()
