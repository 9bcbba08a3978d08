"""``edge-explorer bench explore``: the exploration benchmark (Table I and the coverage figure of the paper)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge_explorer.cli_support import positive_int
from edge_explorer.cluster.units import add_ray_argument
from edge_explorer.commands import bench_oracle

DESCRIPTION = "Exploration benchmark: path length to 95 % coverage per building and method, coverage figure."


def register(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="benchmarks: explore, oracle", description=DESCRIPTION)
    bsub = bench.add_subparsers(dest="bench_command", metavar="ACTION", required=True)
    explore = bsub.add_parser(
        "explore",
        help="fly the exploration methods on buildings; Table I and the coverage-vs-path figure",
        description="Runs every method --runs times per building from one start pose per building (runs differ by "
        "their noise seed) until coverage and correct coverage reach 95 %%, the method has nothing left to explore, "
        "or --max-steps.",
    )
    explore.add_argument(
        "--methods",
        default="frontier,fuel",
        help="comma-separated: frontier, fuel, drl, each optionally +pred (default frontier,fuel)",
    )
    explore.add_argument(
        "--plans",
        default="A,B,C,D",
        help="plan reference(s): A-D, test, a folder, a plan .json or a map_server .yaml (default A,B,C,D)",
    )
    explore.add_argument("--runs", type=positive_int, default=10, help="runs per building and method (default 10)")
    explore.add_argument("--seed", type=int, default=0, help="benchmark seed: start poses and noise (default 0)")
    explore.add_argument("--max-steps", type=positive_int, default=1500, help="step cap per run (default 1500)")
    explore.add_argument(
        "--stop",
        choices=("truth", "map"),
        default="truth",
        help="what ends a run besides the planner running out and --max-steps: truth = 95 %% coverage and correct "
        "coverage against the plan (default); map = the map stop rule, the maps' unverified area below "
        "--stop-threshold-m2 (no truth; false stops are counted against it)",
    )
    explore.add_argument(
        "--stop-threshold-m2",
        type=float,
        help="the map stop rule's threshold on the unverified area, m² (default: the value chosen on val, "
        "edge_explorer.predict.verification.DEFAULT_STOP_THRESHOLD_M2)",
    )
    explore.add_argument(
        "--predictor",
        help="the +pred methods' predictor: a model folder with card.json (e.g. models/predictor), a .safetensors "
        "file, or module:callable",
    )
    explore.add_argument(
        "--policy", help="the drl methods' policy: a model folder with card.json (e.g. models/policy) or a .safetensors"
    )
    explore.add_argument("--workers", type=positive_int, help="processes (default: all cores)")
    add_ray_argument(explore)
    explore.add_argument("--out-dir", type=Path, help="one JSON record per finished run; a rerun skips recorded runs")
    explore.add_argument("--json", type=Path, help="write every figure here")
    explore.add_argument("--plot", type=Path, help="coverage-vs-path-length figure (PNG)")
    explore.add_argument("--markdown", type=Path, help="also write the table here")
    explore.set_defaults(func=_explore)
    bench_oracle.register(bsub)


def _explore(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from edge_explorer.bench import explore as bench
    from edge_explorer.bench.summary import (
        METRICS,
        failures,
        figure_panels,
        markdown_budgets,
        markdown_failures,
        markdown_paired,
        markdown_table,
        paired_differences,
        plot_curves,
        summarize,
    )
    from edge_explorer.cli_support import write_json
    from edge_explorer.world.catalog import load_buildings

    methods = bench.parse_methods(args.methods)
    if args.predictor is not None:
        bench.load_predictor(args.predictor)  # fail now, with one line, not in a worker
    if args.policy is not None:
        bench.load_policy(args.policy)
    from edge_explorer.bench.stops import markdown_stops, stop_summary
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.predict.verification import DEFAULT_STOP_THRESHOLD_M2

    if args.stop_threshold_m2 is not None and (args.stop != "map" or args.stop_threshold_m2 < 0):
        raise EdgeExplorerError("--stop-threshold-m2 takes a value ≥ 0 and goes with --stop map")
    threshold = DEFAULT_STOP_THRESHOLD_M2 if args.stop_threshold_m2 is None else args.stop_threshold_m2
    config = bench.BenchConfig(max_steps=args.max_steps, stop=args.stop, stop_threshold_m2=threshold)
    rasters = load_buildings(args.plans)
    specs = bench.plan_specs(rasters, methods, args.runs, args.seed, config, args.predictor, args.policy)
    workers = args.workers or bench.default_workers()

    def progress(iterable, total):
        return tqdm(iterable, total=total, desc="bench explore", unit="run", mininterval=1.0)

    records = bench.run_benchmark(rasters, specs, workers, args.out_dir, progress, args.ray)
    summary = summarize(records, methods)
    paired = [p for metric in METRICS for p in paired_differences(records, methods, metric)]
    table = markdown_table(summary, methods, per_plan=len(rasters) <= 20)
    if len(methods) > 1:
        for metric in METRICS:
            table += "\n" + markdown_paired([p for p in paired if p["metric"] == metric])
    budgets = markdown_budgets(summary, methods)
    table += "\n" + budgets if budgets else ""
    command = "edge-explorer " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("edge-explorer") else None
    failed = failures(records)
    table += markdown_failures(failed)
    stops = stop_summary(records, methods) if config.stop == "map" else None
    if stops is not None:
        table += markdown_stops(stops, threshold)
    print(table, end="")
    print(f"{len(records)} runs, {len(failed)} without 95 % coverage or with a collision")
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(table)
    panels = figure_panels(records, methods)
    if args.plot is not None:
        plans = args.plans if len(args.plans) <= 40 else f"{len(rasters)} buildings"  # a long list outruns the figure
        title = f"coverage vs path length — {plans}, {args.runs} run(s) per building, seed {args.seed}"
        plot_curves(panels, args.plot, config.coverage_goal, title)
    write_json(
        args.json,
        {
            "command": command,
            "plans": args.plans,
            "methods": methods,
            "runs_per_plan": args.runs,
            "seed": args.seed,
            "config": {
                "coverage_goal": config.coverage_goal,
                "max_steps": config.max_steps,
                "predictor": args.predictor,
                "policy": args.policy,
                **({"stop": "map", "stop_threshold_m2": threshold} if config.stop == "map" else {}),
            },
            **({"stops": stops} if stops is not None else {}),
            "summary": summary,
            "paired": paired,
            "failures": failed,
            "runs": [{k: v for k, v in r.items() if k != "curves"} for r in records],
            "curves": panels,
        },
    )
    return 0
