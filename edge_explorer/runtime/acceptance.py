"""The daemon's acceptance bench: ``edge-explorer run --plans A,B,C,D --runs N [--json --markdown --plot]``.

Every flight is a full ``edge-explorer run`` in its own process (real time, real MAVLink on loopback UDP, the
simulated vehicle and depth camera), one after the other — round by round, run 0 of every building first — so each
daemon's CPU time and peak RSS are its own, as on the drone. Run ``k`` of a building starts where the exploration
benchmark starts on it and uses the benchmark's noise seed of run ``k`` (:func:`edge_explorer.world.seeds.run_seed`),
so path lengths compare with ``bench explore``.

Per building and over all: flights that reached the coverage goal, collisions, the path length when coverage first
reached the goal (min / max / avg / std, as in Table I) and its ratio to the exploration benchmark's average for the
same building and method — the planner the daemon flew, ``+pred`` when it ran the predictor (:func:`bench_method`;
``--compare``, default ``docs/bench/bundled.json``), how many flights lie within ±15 % of that average and how many
of the benchmark's own runs do (the spread of single runs), exploration time, decision latency
p50 / p95 (the worst flight), the daemon's CPU % of one core at the profile's depth rate (mean and worst) and peak
RSS (worst). Each flight's own outputs (summary, picture, telemetry log, daemon log, its terminal output in
``stdout.log``, its command line in ``command.json``) stay in ``--out``/``<plan>-run<k>/``.

Resumable: a flight whose folder already holds a summary written by the same command line is not flown again, so
an interrupted bench (hours of real time for 20 flights) goes on where it stopped; the outputs are rewritten after
every flight. Exit code 0 when every flight
reached the goal without a collision.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from edge_explorer.runtime.options import RunOptions

ACCEPTANCE_TIME_LIMIT_S = 1200.0  # exploration time per flight unless --time-limit-s says otherwise
DEFAULT_COMPARE = Path(__file__).resolve().parents[2] / "docs" / "bench" / "bundled.json"
PATH_TOLERANCE = 0.15  # acceptance: path at the goal within 15 % of the benchmark's


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


def _recorded_flight(out: Path, command: list[str]) -> dict[str, Any] | None:
    """The summary of a flight already flown in ``out`` by the same command line (the interpreter aside), if any."""
    summary, recorded = out / "summary.json", out / "command.json"
    if not (summary.is_file() and recorded.is_file()):
        return None
    try:
        if json.loads(recorded.read_text())[1:] != command[1:]:
            return None
        return json.loads(summary.read_text())
    except (OSError, ValueError, TypeError):
        return None


def run_acceptance(
    options: RunOptions,
    plans: str,
    runs: int,
    json_path: Path | None,
    markdown_path: Path | None = None,
    plot_path: Path | None = None,
    compare_path: Path | None = None,
) -> int:
    """Fly ``runs`` flights on each building of ``plans`` (comma-separated), print and write the table.

    Flights go round by round (run 0 of every building, then run 1, …) and the outputs are rewritten after each
    one, so a bench stopped part-way still reports every building it reached.
    """
    from edge_explorer.world.catalog import load_buildings

    names = [raster.name for raster in load_buildings(plans)]  # fail now, on one line, if a plan is bad
    reference = load_reference(compare_path)
    outputs = (json_path, markdown_path, plot_path)
    flights: list[dict[str, Any]] = []
    interrupted = False
    for run in range(runs):
        for name, plan in zip(names, [p.strip() for p in plans.split(",")], strict=True):
            summary, interrupted = _fly(options, name, plan, run)
            if summary is not None:
                summary["run"] = run
                flights.append(summary)
                print(_flight_line(summary, run), flush=True)
                _write_outputs(outputs, options, plans, runs, reference, compare_path, flights)
            if interrupted:
                break
        if interrupted:
            break
    print(markdown_table(summarize(flights, reference)), end="")
    _write_outputs(outputs, options, plans, runs, reference, compare_path, flights)
    ok = all(f["path_at_goal_m"] is not None and f["collisions"] == 0 for f in flights)
    return 0 if ok and len(flights) == len(names) * runs else 1


def _fly(options: RunOptions, name: str, plan: str, run: int) -> tuple[dict[str, Any] | None, bool]:
    """(the summary of run ``run`` on the building, whether the bench was interrupted): the recorded flight if the
    same command flew it before, else a new flight in its own process."""
    out = options.out_dir / f"{name}-run{run:02d}"
    command = flight_command(options, plan, run, out)
    summary = _recorded_flight(out, command)
    if summary is not None:
        return summary, False
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").unlink(missing_ok=True)
    (out / "command.json").write_text(json.dumps(command) + "\n")
    interrupted = False
    with open(out / "stdout.log", "w") as stdout:
        process = subprocess.Popen(command, stdout=stdout, stderr=subprocess.STDOUT)
        try:
            process.wait()
        except KeyboardInterrupt:  # the flight got the SIGINT too: it holds and writes its summary
            process.wait()
            interrupted = True
    if (out / "summary.json").is_file():
        return json.loads((out / "summary.json").read_text()), interrupted
    print(f"{name} run {run}: no summary (exit code {process.returncode}); see {out / 'daemon.log'}")
    return None, interrupted or process.returncode != 0


def _write_outputs(
    outputs: tuple[Path | None, Path | None, Path | None],
    options: RunOptions,
    plans: str,
    runs: int,
    reference: Reference | None,
    compare_path: Path | None,
    flights: list[dict[str, Any]],
) -> None:
    """The bench so far as JSON, Markdown and PNG (each where a path was given)."""
    from edge_explorer.cli_support import write_json

    json_path, markdown_path, plot_path = outputs
    table = summarize(flights, reference)
    doc = {
        "command": "edge-explorer " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("edge-explorer") else None,
        "plans": plans,
        "runs_per_plan": runs,
        "time_limit_s": options.time_limit_s or ACCEPTANCE_TIME_LIMIT_S,
        "compared_with": None if reference is None else str(compare_path or DEFAULT_COMPARE),
        "summary": table,
        "flights": [{k: v for k, v in f.items() if k not in ("timeline", "path_xy_m")} for f in flights],
    }
    write_json(json_path, doc)
    if markdown_path is not None:
        markdown_path.parent.mkdir(parents=True, exist_ok=True)
        markdown_path.write_text(markdown_report(doc))
    if plot_path is not None and flights:
        plot_acceptance(plot_path, flights, table)


Reference = dict[str, dict[str, list[float]]]
"""The exploration benchmark's paths at the goal, one per run that reached it: ``{method: {building: [metres]}}``
(a file with only the summary gives each building its average as its one path)."""


def bench_method(flight: dict[str, Any]) -> str:
    """The ``bench explore`` method a flight compares with: its planner, plus ``+pred`` when a predictor ran."""
    return flight["planner"] + ("+pred" if flight["backends"]["predictor"] else "")


def load_reference(path: Path | None) -> Reference | None:
    """The exploration benchmark's paths at the goal per method and building, from a ``bench explore`` JSON (its
    per-run records, else its summary's averages); None when there is none (``path`` None and no default)."""
    from edge_explorer.errors import EdgeExplorerError

    if path is None:
        if not DEFAULT_COMPARE.is_file():
            return None
        path = DEFAULT_COMPARE
    try:
        doc = json.loads(path.read_text())
        reference: Reference = {}
        if doc.get("runs"):
            for run in doc["runs"]:
                if run["path_at_coverage_m"] is not None:
                    spec = run["spec"]
                    reference.setdefault(spec["method"], {}).setdefault(spec["plan"], []).append(
                        run["path_at_coverage_m"]
                    )
            return reference
        for plan, methods in doc["summary"]["plans"].items():
            for method, result in methods.items():
                if result["path_at_coverage_m"] is not None:
                    reference.setdefault(method, {})[plan] = [result["path_at_coverage_m"]["avg"]]
        return reference
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise EdgeExplorerError(
            f"--compare {path}: not a `bench explore` JSON ({exc}); give the file that "
            "`edge-explorer bench explore --methods frontier,frontier+pred --json PATH` wrote"
        ) from None


def within_tolerance(paths_m: list[float], reference_m: float) -> int:
    """How many of ``paths_m`` lie within ±:data:`PATH_TOLERANCE` of ``reference_m``."""
    return sum(abs(p / reference_m - 1.0) <= PATH_TOLERANCE for p in paths_m)


def _flight_line(s: dict[str, Any], run: int) -> str:
    at_goal = "–" if s["path_at_goal_m"] is None else f"{s['path_at_goal_m']:.1f} m"
    latency = s["decision_latency_ms"] or {"p50": float("nan"), "p95": float("nan")}
    return (
        f"{s['plan']} run {run}: {s['ending']}, coverage {100 * s['coverage']:.1f} %, path at goal {at_goal}, "
        f"collisions {s['collisions']}, decision p50 {latency['p50']:.1f} / p95 {latency['p95']:.1f} ms "
        f"(CPU p95 {_latency(s, 'p95', 'decision_cpu_ms'):.1f} ms), "
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


def _latency(f: dict[str, Any], key: str, figure: str = "decision_latency_ms") -> float:
    return float("nan") if f.get(figure) is None else f[figure][key]


def _group(flights: list[dict[str, Any]], reference: Reference | None) -> dict[str, Any]:
    """One row of the table; ``reference`` None for the ``all`` row (buildings differ)."""
    methods = sorted({bench_method(f) for f in flights})
    bench_paths: list[float] = []
    if reference is not None and len(methods) == 1:
        bench_paths = reference.get(methods[0], {}).get(flights[0]["plan"], [])
    reference_m = statistics.fmean(bench_paths) if bench_paths else None
    paths = [f["path_at_goal_m"] for f in flights if f["path_at_goal_m"] is not None]
    path = _stats(paths)
    ratio = None if path is None or reference_m is None else path["avg"] / reference_m
    return {
        "flights": len(flights),
        "reached_goal": sum(f["path_at_goal_m"] is not None for f in flights),
        "collisions": sum(f["collisions"] or 0 for f in flights),
        "path_at_goal_m": path,
        "bench_method": "/".join(methods),
        "bench_path_at_goal_m": reference_m,
        "path_ratio_to_bench": ratio,
        "path_within_tolerance": None if ratio is None else abs(ratio - 1.0) <= PATH_TOLERANCE,
        # each flight against the benchmark's average, and the benchmark's own runs against it: the spread of single
        # runs that no flight can beat, since a flight's noise seed changes its decisions as a bench run's does
        "flights_within_tolerance": None if reference_m is None else within_tolerance(paths, reference_m),
        "bench_runs": len(bench_paths) or None,
        "bench_runs_within_tolerance": None if reference_m is None else within_tolerance(bench_paths, reference_m),
        "final_coverage_avg": statistics.fmean(f["coverage"] for f in flights),
        "exploration_s_avg": statistics.fmean(f["exploration_s"] or 0.0 for f in flights),
        "decision_p50_ms_worst": max(_latency(f, "p50") for f in flights),
        "decision_p95_ms_worst": max(_latency(f, "p95") for f in flights),
        "decision_cpu_p95_ms_worst": max(_latency(f, "p95", "decision_cpu_ms") for f in flights),
        "cpu_percent_avg": statistics.fmean(f["cpu"]["daemon_percent_of_one_core"] for f in flights),
        "cpu_percent_worst": max(f["cpu"]["daemon_percent_of_one_core"] for f in flights),
        "peak_rss_mb_worst": max(f["peak_rss_mb"] for f in flights),
        "load_average_1min_avg": statistics.fmean(f["cpu"]["load_average_1min"] for f in flights),
    }


def summarize(flights: list[dict[str, Any]], reference: Reference | None = None) -> dict[str, Any]:
    """Per building (in flight order) and ``all``; ``reference``: the benchmark's average paths
    (:func:`load_reference`), compared per building with the method its flights flew."""
    plans = list(dict.fromkeys(f["plan"] for f in flights))
    out = {plan: _group([f for f in flights if f["plan"] == plan], reference or {}) for plan in plans}
    if flights:
        out["all"] = _group(flights, None)
        for key in ("flights_within_tolerance", "bench_runs", "bench_runs_within_tolerance"):
            counts = [out[plan][key] for plan in plans if out[plan][key] is not None]
            out["all"][key] = sum(counts) if counts else None
    return out


def markdown_table(table: dict[str, Any]) -> str:
    lines = [
        "| building | reached 95 % | collisions | path at 95 % (m) min / max / avg / std | bench method: avg (m) | "
        "ratio | within ±15 % of the bench avg: flights / bench runs | exploration (s) avg | "
        "decision p50 / p95 (ms) worst | decision CPU p95 (ms) worst | CPU % of one core avg / worst | "
        "peak RSS (MB) worst | load avg |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, g in table.items():
        p = g["path_at_goal_m"]
        path = "–" if p is None else f"{p['min']:.1f} / {p['max']:.1f} / {p['avg']:.1f} / {p['std']:.1f}"
        bench = "–" if g["bench_path_at_goal_m"] is None else f"{g['bench_method']}: {g['bench_path_at_goal_m']:.1f}"
        ratio = "–" if g["path_ratio_to_bench"] is None else f"{g['path_ratio_to_bench']:.2f}"
        within = "–"
        if g["flights_within_tolerance"] is not None:
            within = (
                f"{g['flights_within_tolerance']}/{g['flights']} / {g['bench_runs_within_tolerance']}/{g['bench_runs']}"
            )
        lines.append(
            f"| {name} | {g['reached_goal']}/{g['flights']} | {g['collisions']} | {path} | {bench} | {ratio} | "
            f"{within} | {g['exploration_s_avg']:.0f} | "
            f"{g['decision_p50_ms_worst']:.1f} / {g['decision_p95_ms_worst']:.1f} | "
            f"{g['decision_cpu_p95_ms_worst']:.1f} | "
            f"{g['cpu_percent_avg']:.1f} / {g['cpu_percent_worst']:.1f} | {g['peak_rss_mb_worst']:.0f} | "
            f"{g['load_average_1min_avg']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def markdown_report(doc: dict[str, Any]) -> str:
    """The bench as a Markdown page: the command, the table, one line per flight."""
    lines = [
        "# `edge-explorer run` acceptance bench",
        "",
        f"Command: `{doc['command'] or 'edge-explorer run --plans ' + doc['plans']}`; exploration time limit "
        f"{doc['time_limit_s']:.0f} s; path compared with {doc['compared_with'] or 'no benchmark'} (the method each "
        "building's flights flew).",
        "",
        markdown_table(doc["summary"]),
        "| flight | ending | coverage | path at 95 % (m) | collisions | decision p50 / p95 (ms) | "
        "decision CPU p95 (ms) | CPU % | RSS (MB) | load avg |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for f in doc["flights"]:
        at_goal = "–" if f["path_at_goal_m"] is None else f"{f['path_at_goal_m']:.1f}"
        lines.append(
            f"| {f['plan']} run {f.get('run', '?')} | {f['ending']} | {100 * f['coverage']:.1f} % | {at_goal} | "
            f"{f['collisions']} | {_latency(f, 'p50'):.1f} / {_latency(f, 'p95'):.1f} | "
            f"{_latency(f, 'p95', 'decision_cpu_ms'):.1f} | {f['cpu']['daemon_percent_of_one_core']:.1f} | "
            f"{f['peak_rss_mb']:.0f} | {f['cpu']['load_average_1min']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot_acceptance(path: Path, flights: list[dict[str, Any]], table: dict[str, Any]) -> None:
    """Three panels per flight, grouped by building: path at the goal (and the benchmark's average), decision
    latency p50 / p95 (and the 50 ms budget), CPU % of one core and peak RSS (and their ceilings)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plans = [p for p in table if p != "all"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for i, plan in enumerate(plans):
        mine = [f for f in flights if f["plan"] == plan]
        xs = [i + 0.08 * (k - (len(mine) - 1) / 2) for k in range(len(mine))]
        at_goal = [f["path_at_goal_m"] for f in mine]
        axes[0].plot(
            [x for x, v in zip(xs, at_goal, strict=True) if v is not None],
            [v for v in at_goal if v is not None],
            "o",
            color="tab:blue",
            label="daemon" if i == 0 else None,
        )
        missed = [x for x, v in zip(xs, at_goal, strict=True) if v is None]
        axes[0].plot(missed, [0.0] * len(missed), "x", color="tab:red", label="goal not reached" if i == 0 else None)
        bench = table[plan]["bench_path_at_goal_m"]
        if bench is not None:
            axes[0].hlines(bench, i - 0.3, i + 0.3, color="k", label="bench avg, same method" if i == 0 else None)
            axes[0].fill_between(
                [i - 0.3, i + 0.3], bench * (1 - PATH_TOLERANCE), bench * (1 + PATH_TOLERANCE), color="k", alpha=0.1
            )
        axes[1].plot(xs, [_latency(f, "p50") for f in mine], "o", color="tab:blue", label="p50" if i == 0 else None)
        axes[1].plot(xs, [_latency(f, "p95") for f in mine], "^", color="tab:orange", label="p95" if i == 0 else None)
        axes[1].plot(
            xs,
            [_latency(f, "p95", "decision_cpu_ms") for f in mine],
            "D",
            color="tab:purple",
            label="CPU time p95" if i == 0 else None,
        )
        axes[2].plot(
            xs,
            [f["cpu"]["daemon_percent_of_one_core"] for f in mine],
            "o",
            color="tab:blue",
            label="CPU % of one core" if i == 0 else None,
        )
    rss = axes[2].twinx()
    for i, plan in enumerate(plans):
        mine = [f for f in flights if f["plan"] == plan]
        xs = [i + 0.08 * (k - (len(mine) - 1) / 2) for k in range(len(mine))]
        rss.plot(xs, [f["peak_rss_mb"] for f in mine], "s", color="tab:green", label="peak RSS" if i == 0 else None)
    axes[1].axhline(50.0, color="k", ls="--", lw=1, label="budget 50 ms")
    axes[2].axhline(25.0, color="tab:blue", ls="--", lw=1, label="ceiling 25 %")
    rss.axhline(300.0, color="tab:green", ls="--", lw=1, label="ceiling 300 MB")
    rss.set_ylabel("peak RSS (MB)")
    rss.set_ylim(0, 400)
    axes[2].set_ylim(0, 50)
    axes[0].set_ylim(bottom=0)
    axes[1].set_ylim(bottom=0)
    titles = (
        "path when coverage first reached 95 % (m)",
        "decision latency, frame in → waypoint out (ms)",
        "daemon CPU % of one core, peak RSS",
    )
    for ax, title in zip(axes, titles, strict=True):
        ax.set_xticks(range(len(plans)), plans)
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8, loc="lower left")
    rss.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"edge-explorer run: {len(flights)} flights on {', '.join(plans)}", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
