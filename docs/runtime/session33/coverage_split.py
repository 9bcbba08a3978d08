"""Split coverage into what was observed and what the prediction added, along the path, for the daemon's flights and
the benchmark's runs of one building (docs/runtime/README.md, session 33: where the daemon's gain on C comes from).

    python docs/runtime/session33/coverage_split.py daemon --plan C --run-index 0 --out runs/s33/split/daemon_C0.json
    python docs/runtime/session33/coverage_split.py bench --plan C --runs 10 --out runs/s33/split/bench_C.json
    python docs/runtime/session33/coverage_split.py table runs/s33/split/daemon_C*.json vs runs/s33/split/bench_C.json

Each record holds, per decision (daemon) or step (bench): path (m), coverage (observed ∪ thresholded prediction)
and observed coverage (the observed 0.20 m map alone), both on DESIGN.md §7's N_M.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

PATHS_M = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)


def _daemon(args: argparse.Namespace) -> None:
    from edge_explorer.cli import main
    from edge_explorer.mapping.metrics import map_metrics  # noqa: F401 - the truth's metrics use it
    from edge_explorer.runtime.daemon import record as run_record

    rows: list[tuple[float, float, float]] = []
    original = run_record.RunRecord.record_progress

    def record(self, now, odometry, maps, thresholded, phase):  # noqa: ANN001 - the daemon's own signature
        original(self, now, odometry, maps, thresholded, phase)
        if self.truth is not None and self.metrics is not None:
            observed = self.truth.metrics(maps.low, maps.low_grid, None)
            rows.append((self.path_length_m, self.metrics.coverage, observed.coverage))

    run_record.RunRecord.record_progress = record
    out_dir = args.out.with_suffix("")
    code = main(["run", "--plan", args.plan, "--run-index", str(args.run_index), "--no-return", "--out", str(out_dir)])
    _write(args.out, [rows])
    sys.exit(code)


def _bench(args: argparse.Namespace) -> None:
    from edge_explorer.bench import explore as bench
    from edge_explorer.mapping.metrics import map_metrics
    from edge_explorer.plan.goal_policy import GoalPolicyPlanner
    from edge_explorer.predict.predictor import thresholds_of
    from edge_explorer.sim.env import EnvConfig, ExplorationEnv
    from edge_explorer.world.catalog import load_buildings

    raster = load_buildings(args.plan)[0]
    specs = bench.plan_specs([raster], ["drl+pred"], args.runs, 0, predictor="models/predictor", policy="models/policy")
    predictor, policy = bench.load_predictor("models/predictor"), bench.load_policy("models/policy")
    runs = []
    for spec in specs:  # bench.run_episode's loop, with the observed coverage recorded beside it
        config = EnvConfig(coverage_goal=1.0, max_steps=spec.max_steps, thresholds=thresholds_of(predictor))
        env = ExplorationEnv([raster], config, predictor=predictor)
        planner = GoalPolicyPlanner(policy, table=env.table)
        planner.reset()
        _, info = env.reset(seed=spec.seed, options={"start_pose": spec.start_pose})
        truth = env._truth
        rows, previous = [], 0
        while len(rows) <= spec.max_steps:
            observed = map_metrics(env.maps.low, truth.truth_low, truth.interior_low).coverage
            rows.append((info["path_length_m"], info["coverage"], observed))
            if info["coverage"] >= spec.coverage_goal and info["correct_coverage"] >= spec.coverage_goal:
                break
            action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
            if action is None:
                break
            _, _, _, _, info = env.step(action)
            previous = 0 if info["collided"] else action
        runs.append(rows)
    _write(args.out, runs)


def _write(path: Path, runs: list[list[tuple[float, float, float]]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"columns": ["path_m", "coverage", "observed_coverage"], "runs": runs}) + "\n")


def _at(runs: list[list[list[float]]], path_m: float) -> tuple[float, float]:
    """Mean (coverage, observed coverage) at ``path_m`` over the runs that flew that far."""
    values = []
    for rows in runs:
        a = np.asarray(rows, float)
        if a[-1, 0] >= path_m:
            i = int(np.searchsorted(a[:, 0], path_m, side="right")) - 1
            values.append(a[max(i, 0), 1:])
    return tuple(np.mean(values, axis=0)) if values else (float("nan"), float("nan"))


def _table(args: argparse.Namespace) -> None:
    split = args.files.index("vs")
    groups = {"daemon": args.files[:split], "bench": args.files[split + 1 :]}
    print("path (m) | " + " | ".join(f"{g}: coverage / observed / added" for g in groups))
    for path_m in PATHS_M:
        cells = []
        for files in groups.values():
            runs = [r for f in files for r in json.loads(Path(f).read_text())["runs"]]
            cov, obs = _at(runs, path_m)
            cells.append(f"{cov:.3f} / {obs:.3f} / {cov - obs:+.3f}")
        print(f"{path_m:>5.0f} | " + " | ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    daemon = sub.add_parser("daemon")
    daemon.add_argument("--plan", default="C")
    daemon.add_argument("--run-index", type=int, default=0)
    daemon.add_argument("--out", type=Path, required=True)
    bench = sub.add_parser("bench")
    bench.add_argument("--plan", default="C")
    bench.add_argument("--runs", type=int, default=10)
    bench.add_argument("--out", type=Path, required=True)
    table = sub.add_parser("table")
    table.add_argument("files", nargs="+", help="daemon files, then the word vs, then bench files")
    args = parser.parse_args()
    {"daemon": _daemon, "bench": _bench, "table": _table}[args.command](args)


if __name__ == "__main__":
    main()
