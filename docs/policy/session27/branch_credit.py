"""Per-decision credit for the goal policy by branching (issue #21, session 27): one step of rollout policy
improvement.

Self-imitation (sessions 24–26) credits a whole sampled flight, and a flight's length spreads by ~5 m over its
samples, so the credit for any one goal choice is mostly noise. Here every credit is for one decision: on a train
plan the greedy policy flies the benchmark's run 0 once (the *base* flight, deterministic for a start and noise seed)
and at ``--branches`` of its decisions, drawn at random, ``--alternatives`` other goal cells are tried — the policy's
next-best cells, at least ``--spacing`` goal cells (0.8 m each) apart from the greedy one and from each other — each
followed by the greedy policy to the end of the flight (the flight is re-flown from the start with the same choices
up to the branch, so the states before it are the base flight's). A decision's credit is the path at 95 % coverage
of each branch against the base flight's: the rollout estimate of Q(s, goal) under the greedy policy.

``labels.py`` turns the branch records into goal-demo shards (the best branch where it wins by a margin, the greedy
cell where it wins by one) for ``edge-explorer train goal-bc --init models/policy/policy.safetensors``::

    python docs/policy/session27/branch_credit.py --first 3400 --count 200 --out runs/s27/branch/train

Train plans only; written one block of plans at a time (a run cut off keeps every finished block, and a rerun with
the same ``--out`` skips finished blocks).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.goal_policy import GoalPolicyPlanner, goal_at_cell, goal_decision, weighted_scores
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans
from edge_explorer.world.plan import FloorPlan
from edge_explorer.world.raster import PlanRaster

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # docs/policy: the sweep's benchmark run
from expert_sweep import fly_run  # noqa: E402

_WORKER: dict = {}


class BranchingPlanner(GoalPolicyPlanner):
    """The greedy goal planner, except that decision ``branch_at`` takes ``branch_cell``; with ``record`` every
    decision's observation, valid mask and weighted scores are kept."""

    def __init__(self, policy, table, branch_at: int = -1, branch_cell: int = -1, record: bool = False) -> None:
        super().__init__(policy, table=table)
        self.branch_at, self.branch_cell, self.record = branch_at, branch_cell, record
        self.decisions = 0
        self.records: list[dict] = []
        self.env: ExplorationEnv | None = None  # set by _flight: each record notes the coverage it was taken at

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return super().select_goal(view, pose)
        scores = weighted_scores(
            self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
        ).ravel()
        index, self.decisions = self.decisions, self.decisions + 1
        cell = self.branch_cell if index == self.branch_at else int(np.argmax(scores))
        if self.record:
            o = decision.observation
            self.records.append(
                {
                    "high": o["high"],
                    "thres": o["thres"],
                    "last": self.last_action,
                    "mask": decision.options.flat_mask(),
                    "scores": scores,
                    "cell": cell,
                    "coverage": self.env._metrics.coverage,  # noqa: SLF001 - the env's coverage at this decision
                }
            )
        return goal_at_cell(view, decision, cell)


def alternatives(scores: np.ndarray, greedy: int, count: int, spacing: int) -> list[int]:
    """The best-scoring valid cells after ``greedy``, each at least ``spacing`` goal cells (Chebyshev) away from
    ``greedy`` and from the ones taken before it."""
    taken = [divmod(greedy, GOAL_GRID_CELLS)]
    chosen: list[int] = []
    for cell in np.argsort(-scores, kind="stable"):
        if not np.isfinite(scores[cell]) or len(chosen) == count:
            break
        rc = divmod(int(cell), GOAL_GRID_CELLS)
        if all(max(abs(rc[0] - r), abs(rc[1] - c)) >= spacing for r, c in taken):
            taken.append(rc)
            chosen.append(int(cell))
    return chosen


def _init(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    _WORKER.update(args=args, predictor=bench.load_predictor(args.predictor), policy=bench.load_policy(args.policy))


def _flight(raster: PlanRaster, branch_at: int = -1, branch_cell: int = -1, record: bool = False, planner_cls=None):
    """(path at 95 % coverage, or None when the run did not reach 95 % and 95 % correct coverage without a
    collision; the planner)."""
    predictor = _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    config = EnvConfig(coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = (planner_cls or BranchingPlanner)(_WORKER["policy"], env.table, branch_at, branch_cell, record)
    planner.env = env
    at_goal, collisions, _, done = fly_run(env, planner, raster, max_steps)
    return (at_goal if done and collisions == 0 else None), planner


def plan_branches(indexed: tuple[int, FloorPlan]) -> dict:
    """The base flight on one plan and its branches (see the module docstring)."""
    index, plan = indexed
    args = _WORKER["args"]
    raster = plan_to_raster(plan)
    base, planner = _flight(raster, record=True)
    row: dict = {"plan": raster.name, "base": base, "decisions": planner.decisions, "points": []}
    if base is None:
        return row
    rng = np.random.default_rng([args.seed, index])
    # only decisions taken before 95 % coverage: later ones cannot change the path at 95 %
    early = [k for k, rec in enumerate(planner.records) if rec["coverage"] < 0.95]
    for k in sorted(rng.choice(early, size=min(args.branches, len(early)), replace=False)):
        rec = planner.records[k]
        cells = alternatives(rec["scores"], rec["cell"], args.alternatives, args.spacing)
        paths = [_flight(raster, int(k), cell)[0] for cell in cells]
        row["points"].append({"decision": int(k), "greedy": rec["cell"], "cells": cells, "paths": paths, "record": rec})
    return row


def _indexed(indexed: tuple[int, FloorPlan]) -> tuple[int, dict]:
    return indexed[0], plan_branches(indexed)


def _write_block(out: Path, block_index: int, rows: list[dict]) -> None:
    """One block: the branch points' observations (npz) and every flight's figures (json)."""
    points = [p for r in rows for p in r["points"]]
    arrays = {
        "high": np.array([p["record"]["high"] for p in points], dtype=np.int8),
        "thres": np.array([p["record"]["thres"] for p in points], dtype=np.int8),
        "last": np.array([p["record"]["last"] for p in points], dtype=np.int64),
        "mask": np.array([p["record"]["mask"] for p in points], dtype=bool),
        "scores": np.array([p["record"]["scores"] for p in points], dtype=np.float32),
    }
    np.savez_compressed(out / f"block-{block_index:05d}.npz", **arrays)
    for r in rows:
        for p in r["points"]:
            p.pop("record")
    (out / f"block-{block_index:05d}.json").write_text(json.dumps(rows))


def add_flight_args(parser: argparse.ArgumentParser) -> None:
    """The options every branching script shares: seed, models, plan shards, worker processes."""
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy/policy.safetensors")
    parser.add_argument("--plans", type=Path, default=Path("data/plans/train"))
    parser.add_argument("--workers", type=int, default=2)


def add_branch_args(parser: argparse.ArgumentParser, spacing: int) -> None:
    """The options of a branching collection: which train plans, where to, how many branches, plus
    :func:`add_flight_args`."""
    parser.add_argument("--first", type=int, required=True, help="first train plan")
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--branches", type=int, default=3, help="decisions branched per plan")
    parser.add_argument("--alternatives", type=int, default=3, help="other goal cells tried per branched decision")
    parser.add_argument("--spacing", type=int, default=spacing, help="goal cells between tried cells (Chebyshev)")
    parser.add_argument("--block", type=int, default=8, help="plans per written block")
    add_flight_args(parser)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_branch_args(parser, spacing=2)
    run_blocks(parser.parse_args(), _indexed, _write_block, "branch credit")


def run_blocks(args: argparse.Namespace, plan_fn, write_block, desc: str) -> None:
    """Run ``plan_fn((index, plan)) -> (index, row)`` over train plans ``--first`` … ``--first + --count`` in
    ``--workers`` processes and hand each finished block of ``--block`` rows to ``write_block(out, start, rows)``;
    blocks whose ``block-*.json`` exists are skipped (a rerun resumes)."""
    shards = sorted(args.plans.glob("*.jsonl.gz"))
    if not shards:
        raise SystemExit(f"{args.plans}: no plan shards; generate them with `edge-explorer plans generate`")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "args.json").write_text(json.dumps({k: str(v) for k, v in vars(args).items()}, indent=1))
    blocks = range(args.first, args.first + args.count, args.block)
    todo = {s for s in blocks if not (args.out / f"block-{s:05d}.json").is_file()}
    plans = itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)
    work = (
        (i, p)
        for i, p in enumerate(plans, start=args.first)
        if args.first + (i - args.first) // args.block * args.block in todo
    )
    with Pool(args.workers, initializer=_init, initargs=(args,)) as pool:
        rows: list[dict] = []
        for index, row in tqdm(pool.imap(plan_fn, work), total=len(todo) * args.block, desc=desc):
            rows.append(row)
            start = args.first + (index - args.first) // args.block * args.block
            if index == min(start + args.block, args.first + args.count) - 1:
                write_block(args.out, start, rows)
                rows = []


if __name__ == "__main__":
    main()
