"""Per-decision Q estimates for the goal policy, every tried cell flown with fresh noise (issue #21, session 28).

Session 27's branch credit (``session27/branch_credit.py``) paired each alternative's one flight with the *base*
flight, whose noise is the benchmark's own and can be lucky (its noise probe: one choice re-flown spreads by 2.3 m,
different choices by 7.0 m). Here every tried cell — the greedy cell included — is flown from the branched decision
with the simulator's noise reseeded there (``--reseeds`` flights per cell, the same reseeds for every cell: common
random numbers), so each cell gets a rollout estimate of Q(s, cell) under the greedy policy on equal terms, and the
base flight's own noise plays no part. The observations of the branched decisions and of ``--anchors`` other
decisions per base flight (with the shipped policy's scores, for a distillation anchor) go to ``block-*.npz``; the
flights' figures to ``block-*.json``. ``soft_q_bc.py`` trains on them::

    PYTHONPATH=docs/policy:docs/policy/session27 python docs/policy/session28/branch_q.py \
        --first 3400 --count 400 --out runs/s28/branchq

Train plans only; resumable by block, like session 27's script.
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

import branch_credit as bc
import numpy as np
from noise_probe import ReseedingPlanner

from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.plan import FloorPlan


def _arrays(records: list[dict]) -> dict[str, np.ndarray]:
    return {
        "high": np.array([r["high"] for r in records], dtype=np.int8).reshape(len(records), 237, 237),
        "thres": np.array([r["thres"] for r in records], dtype=np.int8).reshape(len(records), 237, 237),
        "last": np.array([r["last"] for r in records], dtype=np.int64),
        "mask": np.array([r["mask"] for r in records], dtype=bool).reshape(len(records), -1),
        "scores": np.array([r["scores"] for r in records], dtype=np.float32).reshape(len(records), -1),
    }


def plan_q(indexed: tuple[int, FloorPlan]) -> dict:
    """The base flight on one plan, its branched decisions' Q estimates and its anchor decisions."""
    index, plan = indexed
    args = bc._WORKER["args"]
    raster = plan_to_raster(plan)
    base, planner = bc._flight(raster, record=True)
    row: dict = {"plan": raster.name, "base": base, "decisions": planner.decisions, "points": [], "anchors": []}
    if base is None:
        return row
    rng = np.random.default_rng([args.seed, index])
    row["anchors"] = [
        planner.records[int(k)]
        for k in sorted(rng.choice(len(planner.records), size=min(args.anchors, len(planner.records)), replace=False))
    ]
    early = [k for k, rec in enumerate(planner.records) if rec["coverage"] < 0.95]
    for k in sorted(rng.choice(early, size=min(args.branches, len(early)), replace=False)):
        rec = planner.records[int(k)]
        cells = [rec["cell"], *bc.alternatives(rec["scores"], rec["cell"], args.alternatives, args.spacing)]
        paths: list[list[float | None]] = []
        for cell in cells:
            flights = []
            for r in range(args.reseeds):
                reseed = int(np.random.SeedSequence([args.seed, index, int(k), r]).generate_state(1)[0])
                planner_cls = functools.partial(ReseedingPlanner, reseed=reseed)
                flights.append(bc._flight(raster, int(k), cell, planner_cls=planner_cls)[0])
            paths.append(flights)
        row["points"].append({"decision": int(k), "cells": cells, "paths": paths, "record": rec})
    return row


def _write_block(out: Path, block_index: int, rows: list[dict]) -> None:
    points = [p["record"] for r in rows for p in r["points"]]
    anchors = [a for r in rows for a in r["anchors"]]
    arrays = {f"point_{k}": v for k, v in _arrays(points).items()} if points else {}
    arrays |= {f"anchor_{k}": v for k, v in _arrays(anchors).items()} if anchors else {}
    np.savez_compressed(out / f"block-{block_index:05d}.npz", **arrays)
    for r in rows:
        for p in r["points"]:
            p.pop("record")
        r["anchors"] = len(r["anchors"])
    (out / f"block-{block_index:05d}.json").write_text(json.dumps(rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bc.add_branch_args(parser, spacing=3)
    parser.add_argument("--reseeds", type=int, default=1, help="flights per tried cell, noise reseeded")
    parser.add_argument("--anchors", type=int, default=4, help="decisions per base flight kept for distillation")
    bc.run_blocks(parser.parse_args(), _indexed, _write_block, "branch Q")


def _indexed(indexed: tuple[int, FloorPlan]) -> tuple[int, dict]:
    return indexed[0], plan_q(indexed)


if __name__ == "__main__":
    main()
