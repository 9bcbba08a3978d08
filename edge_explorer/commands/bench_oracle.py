"""``edge-explorer bench oracle``: the perfect-knowledge yardstick per building (:mod:`edge_explorer.bench.oracle`),
and, given a ``bench explore --json`` report, every method's ratio to it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge_explorer.cli_support import positive_int


def register(bsub: argparse._SubParsersAction) -> None:
    """Add ``oracle`` to the ``bench`` actions."""
    oracle = bsub.add_parser(
        "oracle",
        help="the path a perfect-knowledge explorer needs to 95 %% coverage, and every method's ratio to it",
        description="Greedy cover of N_M by full-turn viewpoints, then an open OR-Tools tour through them from the "
        "bench's start pose along flyable paths (edge_explorer/bench/oracle.py).",
    )
    oracle.add_argument("--plans", default="A,B,C,D", help="plan reference(s), as for bench explore (default A,B,C,D)")
    oracle.add_argument("--first", type=positive_int, help="only the first N plans of --plans (e.g. of test)")
    oracle.add_argument("--seed", type=int, default=0, help="benchmark seed of the start poses (default 0)")
    oracle.add_argument("--goal", type=float, default=0.95, help="coverage goal (default 0.95)")
    oracle.add_argument("--compare", type=Path, help="a bench explore --json report: add each method's ratio")
    oracle.add_argument("--json", type=Path, help="write every figure here")
    oracle.add_argument("--markdown", type=Path, help="also write the table(s) here")
    oracle.set_defaults(func=_oracle)


def _oracle(args: argparse.Namespace) -> int:
    from edge_explorer.bench.oracle import oracle_path
    from edge_explorer.bench.summary import markdown_oracle, oracle_ratios
    from edge_explorer.cli_support import write_json
    from edge_explorer.sim.starts import start_pose
    from edge_explorer.world.catalog import load_buildings

    rasters = load_buildings(args.plans)[: args.first]
    results = [oracle_path(r, start_pose(r, args.seed), args.goal) for r in rasters]
    lines = [
        "| building | oracle at goal (m) | tour (m) | viewpoints | N_M covered | N_M cells | candidates | solve (s) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for res in results:
        capped = " (time cap)" if res.tour_capped else ""
        lines.append(
            f"| {res.plan} | {_m(res.path_at_goal_m)} | {res.path_m:.1f} | {len(res.tour)} | "
            f"{100 * res.coverage:.1f} % | {res.n_m} | {res.candidates} | {res.solve_s:.2f}{capped} |"
        )
    table = "\n".join(lines) + "\n"
    # the ratios use the path at which the oracle's flight first reaches the goal, as the bench measures methods
    oracle_m = {res.plan: res.path_at_goal_m for res in results if res.path_at_goal_m is not None}
    report: dict[str, object] = {
        "command": "edge-explorer " + " ".join(sys.argv[1:]),
        "plans": args.plans,
        "seed": args.seed,
        "goal": args.goal,
        "oracle": [res.as_dict() for res in results],
    }
    if args.compare is not None:
        bench = json.loads(args.compare.read_text())
        if bench.get("seed") != args.seed:
            print(
                f"warning: {args.compare} was flown with seed {bench.get('seed')}: other start poses", file=sys.stderr
            )
        table += "\n" + markdown_oracle(bench["summary"], bench["methods"], oracle_m)
        report["compare"] = str(args.compare)
        report["ratios"] = oracle_ratios(bench["summary"], bench["methods"], oracle_m)
    print(table, end="")
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(table)
    write_json(args.json, report)
    return 0


def _m(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f}"
