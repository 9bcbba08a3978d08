"""Re-fly one drl+pred benchmark run from its record and draw its path and goals (issue #21, session 35).

The run's spec (start pose, noise seed) comes from a ``bench explore`` JSON, so the figure is that record's run;
the planner, predictor and policy are the ones the benchmark flew. Drawn with session 20's ``trace_run.draw``::

    python docs/policy/session35/trace_drl.py docs/bench/policy_bundled.json D 6 docs/policy/session35/D_drl_run06.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from edge_explorer.bench import explore as bench
from edge_explorer.plan.goal_policy import GoalPolicyPlanner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import load_building, plan_to_raster
from edge_explorer.world.dataset import DEFAULT_SEED, generate_checked

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "session20"))
from trace_run import draw, trace_flight  # noqa: E402


def record_spec(bench_json: str, plan: str, run: int, method: str = "drl+pred") -> dict:
    """The spec of ``method``'s run ``run`` on ``plan`` in a benchmark JSON."""
    for record in json.loads(Path(bench_json).read_text())["runs"]:
        spec = record["spec"]
        if spec["method"] == method and spec["plan"] == plan and spec["run"] == run:
            return spec
    raise SystemExit(f"{bench_json}: no {method} run {run} on {plan}")


def raster_of(plan: str):  # noqa: ANN201 - a PlanRaster
    """A bundled building, a plan file, or a test-split plan by its benchmark name (``test-00051``)."""
    if plan.startswith("test-"):
        return plan_to_raster(generate_checked(DEFAULT_SEED, "test", int(plan.removeprefix("test-"))))
    return load_building(plan)


def fly(spec: dict, predictor_ref: str, policy_ref: str) -> dict:
    """Path, coverage and goals of the run ``spec`` describes (stops at 95 % coverage and correct coverage)."""
    raster = raster_of(spec["plan"])
    predictor = bench.load_predictor(predictor_ref)
    config = EnvConfig(coverage_goal=1.0, max_steps=spec["max_steps"], thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = GoalPolicyPlanner(bench.load_policy(policy_ref), table=env.table)
    planner.reset()
    _, info = env.reset(seed=spec["seed"], options={"start_pose": np.asarray(spec["start_pose"])})
    return trace_flight(env, planner, info, config.max_steps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bench_json")
    parser.add_argument("plan")
    parser.add_argument("run", type=int)
    parser.add_argument("png")
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy/policy.safetensors")
    args = parser.parse_args()
    trace = fly(record_spec(args.bench_json, args.plan, args.run), args.predictor, args.policy)
    draw(trace, f"{args.plan} drl+pred run {args.run}", args.png)
    print(f"{args.png}: path at 95 % {trace['path_at_95']}, {len(trace['goals'])} goals")
    for k, (path_m, cov, gx, gy) in enumerate(trace["goals"]):
        print(f"  goal {k:2d} at {path_m:5.1f} m, coverage {cov:.3f} -> ({gx:5.1f}, {gy:5.1f})")


if __name__ == "__main__":
    main()
