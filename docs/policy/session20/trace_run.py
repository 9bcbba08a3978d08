"""Fly one benchmark run and draw its path and goals on the truth (issue #21 diagnostics, session 20).

The run is ``bench explore``'s own (start pose, noise seed, end rule, the shipped int8 predictor), so the figure
belongs to the record of that method, building and run; the path at 95 % coverage is read as the benchmark reads it
(the first step at or above 95 %). Left: the ground truth, the flown path (blue), the start (green star) and each goal
the planner chose, numbered in order (red). Right: coverage against path length, with the goal numbers where each
goal was chosen::

    python docs/policy/session20/trace_run.py A predfrontier+pred 3 docs/policy/session20/A_expert_run03.png
"""

from __future__ import annotations

import argparse

import matplotlib
import numpy as np

from edge_explorer.bench import explore as bench
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import load_building
from edge_explorer.world.grid import FREE, OCCUPIED

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def fly(plan: str, method: str, run: int, predictor_ref: str = "models/predictor") -> dict:
    """Path, coverage and goals of one benchmark run (methods without ``drl``)."""
    raster = load_building(plan)
    predictor = bench.load_predictor(predictor_ref) if method.endswith(bench.PRED_SUFFIX) else None
    config = EnvConfig(coverage_goal=1.0, max_steps=bench.BenchConfig().max_steps, thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = bench.PLANNERS[method.removesuffix(bench.PRED_SUFFIX)](env.table)
    planner.reset()
    seed = bench.run_seed(0, raster.name, run)
    _, info = env.reset(seed=seed, options={"start_pose": bench.start_pose(raster, 0)})
    return trace_flight(env, planner, info, config.max_steps)


def trace_flight(env: ExplorationEnv, planner, info: dict, max_steps: int) -> dict:  # noqa: ANN001 - a GoalPlanner
    """Fly ``planner`` in the freshly reset ``env`` (``info`` from its reset) until 95 % coverage and correct coverage
    or ``max_steps``: path, coverage and the goals chosen (path, coverage and goal position when each was chosen)."""
    xy, coverage, path, goals, previous, last = [env.pose[:2]], [info["coverage"]], [0.0], [], 0, None
    while (coverage[-1] < 0.95 or info["correct_coverage"] < 0.95) and len(path) <= max_steps:
        action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
        if action is None:
            break
        goal = planner._goal  # the goal now being flown (a diagnostic reads the loop's state)
        if goal is not None and goal is not last:
            goals.append((path[-1], coverage[-1], *goal.path_xy_m[-1]))
            last = goal
        _, _, _, _, info = env.step(action)
        previous = 0 if info["collided"] else action
        xy.append(env.pose[:2])
        coverage.append(info["coverage"])
        path.append(info["path_length_m"])
    hits = np.flatnonzero(np.asarray(coverage) >= 0.95)
    return {
        "truth": env._truth.truth_low,
        "grid": env.maps.low_grid,
        "xy": np.array(xy),
        "coverage": coverage,
        "path": path,
        "goals": goals,
        "path_at_95": float(path[hits[0]]) if len(hits) else None,
    }


def draw(trace: dict, title: str, png: str) -> None:
    truth, grid = trace["truth"], trace["grid"]
    (x0, x1), (y0, y1) = (
        (grid.center_of(0, 0)[0], grid.center_of(0, truth.shape[1] - 1)[0]),
        (
            grid.center_of(0, 0)[1],
            grid.center_of(truth.shape[0] - 1, 0)[1],
        ),
    )
    image = np.where(truth == OCCUPIED, 0.0, np.where(truth == FREE, 1.0, 0.6))
    fig, (ax, curve) = plt.subplots(1, 2, figsize=(13, 5), constrained_layout=True)
    ax.imshow(image, cmap="gray", origin="lower" if y1 > y0 else "upper", extent=[x0, x1, min(y0, y1), max(y0, y1)])
    ax.plot(trace["xy"][:, 0], trace["xy"][:, 1], "b-", lw=1)
    ax.plot(*trace["xy"][0], "g*", ms=12)
    for k, (path_m, cov, gx, gy) in enumerate(trace["goals"]):
        ax.plot(gx, gy, "r.", ms=5)
        ax.text(gx, gy, str(k), fontsize=6, color="r")
        curve.text(path_m, cov, str(k), fontsize=6, color="r")
    at = trace["path_at_95"]
    ax.set(title=f"{title}: path at 95 % coverage {at:.1f} m" if at else title, xlabel="x (m)", ylabel="y (m)")
    curve.plot(trace["path"], trace["coverage"])
    curve.axhline(0.95, ls=":", color="k")
    curve.set(xlabel="path length (m)", ylabel="coverage", title="coverage; red: where each goal was chosen")
    fig.savefig(png, dpi=80)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plan", help="building reference: A-D, a plan .json or a map_server .yaml")
    parser.add_argument("method", help="frontier, fuel or predfrontier, each optionally +pred")
    parser.add_argument("run", type=int, help="run index: the benchmark's noise seed")
    parser.add_argument("png")
    args = parser.parse_args()
    trace = fly(args.plan, args.method, args.run)
    draw(trace, f"{args.plan} {args.method} run {args.run}", args.png)
    print(f"{args.png}: path at 95 % {trace['path_at_95']}, {len(trace['goals'])} goals")


if __name__ == "__main__":
    main()
