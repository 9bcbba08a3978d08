"""The daemon's acceptance bench: ``edge-explorer run --plans A,B,C,D --runs N [--json OUT]``.

Every flight is a full ``edge-explorer run`` in its own process (real time, real MAVLink on loopback UDP, the
simulated vehicle and depth camera), one after the other: each daemon's CPU time and peak RSS are its own, as on
the drone. Run ``k`` of a building starts where the exploration benchmark starts on it and uses the benchmark's
noise seed of run ``k`` (:func:`edge_explorer.bench.explore.run_seed`), so path lengths compare with
``bench explore``.

Per building and over all: flights that reached the coverage goal, collisions, the path length when coverage first
reached the goal (min / max / avg / std, as in Table I), exploration time, decision latency p95 (the worst flight),
the daemon's CPU % of one core at the profile's depth rate (mean and worst) and peak RSS (worst). Each flight's own
outputs (summary, picture, telemetry log, daemon log, its terminal output in ``stdout.log``) stay in
``--out``/``<plan>-run<k>/``. Exit code 0 when every flight reached the goal without a collision.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from edge_explorer.runtime.cli import RunOptions

ACCEPTANCE_TIME_LIMIT_S = 1200.0  # exploration time per flight unless --time-limit-s says otherwise


def flight_command(options: RunOptions, plan: str, run: int, out: Path) -> list[str]:
    """The ``edge-explorer run`` command line of one flight."""
    command = [
        sys.executable,
        "-m",
        "edge_explorer.cli",
        "run",
        "--plan",
        plan,
        "--run-index",
        str(run),
        "--out",
        str(out),
        "--planner",
        options.planner,
        "--profile",
        options.profile,
        "--seed",
        str(options.seed),
        "--models",
        str(options.models_dir),
        "--autopilot",
        options.autopilot,
        "--time-limit-s",
        str(options.time_limit_s or ACCEPTANCE_TIME_LIMIT_S),
    ]
    return command if options.return_home else [*command, "--no-return"]


def run_acceptance(options: RunOptions, plans: str, runs: int, json_path: Path | None) -> int:
    """Fly ``runs`` flights on each building of ``plans`` (comma-separated) and print the table."""
    from edge_explorer.cli import write_json
    from edge_explorer.world.catalog import load_buildings

    names = [raster.name for raster in load_buildings(plans)]  # fail now, on one line, if a plan is bad
    flights: list[dict[str, Any]] = []
    interrupted = False
    for name, plan in zip(names, [p.strip() for p in plans.split(",")], strict=True):
        for run in range(runs):
            out = options.out_dir / f"{name}-run{run:02d}"
            out.mkdir(parents=True, exist_ok=True)
            with open(out / "stdout.log", "w") as stdout:
                process = subprocess.Popen(
                    flight_command(options, plan, run, out), stdout=stdout, stderr=subprocess.STDOUT
                )
                try:
                    process.wait()
                except KeyboardInterrupt:  # the flight got the SIGINT too: it holds and writes its summary
                    process.wait()
                    interrupted = True
            summary_path = out / "summary.json"
            if not summary_path.is_file():
                print(f"{name} run {run}: no summary (exit code {process.returncode}); see {out / 'daemon.log'}")
                interrupted = interrupted or process.returncode != 0
            else:
                flights.append(json.loads(summary_path.read_text()))
                print(_flight_line(flights[-1], run), flush=True)
            if interrupted:
                break
        if interrupted:
            break
    table = summarize(flights)
    print(markdown_table(table), end="")
    write_json(
        json_path,
        {
            "command": "edge-explorer " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("edge-explorer") else None,
            "plans": plans,
            "runs_per_plan": runs,
            "time_limit_s": options.time_limit_s or ACCEPTANCE_TIME_LIMIT_S,
            "summary": table,
            "flights": [{k: v for k, v in f.items() if k not in ("timeline", "path_xy_m")} for f in flights],
        },
    )
    ok = all(f["path_at_goal_m"] is not None and f["collisions"] == 0 for f in flights)
    return 0 if ok and len(flights) == len(names) * runs else 1


def _flight_line(s: dict[str, Any], run: int) -> str:
    at_goal = "–" if s["path_at_goal_m"] is None else f"{s['path_at_goal_m']:.1f} m"
    return (
        f"{s['plan']} run {run}: {s['ending']}, coverage {100 * s['coverage']:.1f} %, path at goal {at_goal}, "
        f"collisions {s['collisions']}, decision p95 {s['decision_latency_ms']['p95']:.1f} ms, "
        f"CPU {s['cpu']['daemon_percent_of_one_core']:.1f} %, peak RSS {s['peak_rss_mb']:.0f} MB"
    )


def _stats(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    return {
        "min": min(values),
        "max": max(values),
        "avg": statistics.fmean(values),
        "std": statistics.pstdev(values),
    }


def _group(flights: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "flights": len(flights),
        "reached_goal": sum(f["path_at_goal_m"] is not None for f in flights),
        "collisions": sum(f["collisions"] or 0 for f in flights),
        "path_at_goal_m": _stats([f["path_at_goal_m"] for f in flights if f["path_at_goal_m"] is not None]),
        "final_coverage_avg": statistics.fmean(f["coverage"] for f in flights),
        "exploration_s_avg": statistics.fmean(f["exploration_s"] or 0.0 for f in flights),
        "decision_p95_ms_worst": max(f["decision_latency_ms"]["p95"] for f in flights),
        "cpu_percent_avg": statistics.fmean(f["cpu"]["daemon_percent_of_one_core"] for f in flights),
        "cpu_percent_worst": max(f["cpu"]["daemon_percent_of_one_core"] for f in flights),
        "peak_rss_mb_worst": max(f["peak_rss_mb"] for f in flights),
        "load_average_1min_avg": statistics.fmean(f["cpu"]["load_average_1min"] for f in flights),
    }


def summarize(flights: list[dict[str, Any]]) -> dict[str, Any]:
    """Per building (in flight order) and ``all``."""
    plans = list(dict.fromkeys(f["plan"] for f in flights))
    out = {plan: _group([f for f in flights if f["plan"] == plan]) for plan in plans}
    if flights:
        out["all"] = _group(flights)
    return out


def markdown_table(table: dict[str, Any]) -> str:
    lines = [
        "| building | reached 95 % | collisions | path at 95 % (m) min / max / avg / std | exploration (s) avg | "
        "decision p95 (ms) worst | CPU % of one core avg / worst | peak RSS (MB) worst |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, g in table.items():
        p = g["path_at_goal_m"]
        path = "–" if p is None else f"{p['min']:.1f} / {p['max']:.1f} / {p['avg']:.1f} / {p['std']:.1f}"
        lines.append(
            f"| {name} | {g['reached_goal']}/{g['flights']} | {g['collisions']} | {path} | "
            f"{g['exploration_s_avg']:.0f} | {g['decision_p95_ms_worst']:.1f} | "
            f"{g['cpu_percent_avg']:.1f} / {g['cpu_percent_worst']:.1f} | {g['peak_rss_mb_worst']:.0f} |"
        )
    return "\n".join(lines) + "\n"
