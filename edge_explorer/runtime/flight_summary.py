"""What one flight leaves behind: ``summary.json`` (the run summary) and ``summary.png`` (the run's picture), and
the one-line summary printed at the end of ``edge-explorer run``."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from edge_explorer.runtime.options import RunOptions


def run_summary(
    options: RunOptions,
    profile: Any,
    model_notes: tuple[str, ...],
    backends: dict[str, str | None],
    raster: Any,
    start: tuple[float, float, float] | None,
    noise_seed: int,
    report: Any,
    collisions: int | None,
    vehicle_cpu_s: float,
    memory_mb: dict[str, Any],
    daemon: Any,
) -> dict[str, Any]:
    """The run summary (``summary.json``): the flight's setup, the daemon's report and the process's CPU and memory."""
    simulated = options.source == "sim"
    daemon_cpu_s = report.process_cpu_s - vehicle_cpu_s - (report.source_cpu_s if simulated else 0.0)
    stages = {name: vars(s) for name, s in report.stages.items()}
    decision = report.stages.get("decision")
    decision_cpu = report.stages.get("decision_cpu")
    return {
        "format": "edge-explorer/run-summary",
        "command": "edge-explorer " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("edge-explorer") else None,
        "plan": None if raster is None else raster.name,
        "source": options.source,
        "connect": options.connect or "simulated vehicle (loopback UDP)",
        "profile": profile.name,
        "seed": options.seed,
        "noise_seed": noise_seed,
        "start_pose": start,
        "planner": report.planner,
        "models": list(model_notes),
        "backends": backends,
        "ending": report.ending,
        "why": explain_ending(report, daemon),
        "coverage": report.coverage,
        "correct_coverage": report.correct_coverage,
        "observed_coverage": report.observed_coverage,
        "f1": report.f1,
        "path_length_m": report.path_length_m,
        "path_at_goal_m": report.path_at_goal_m,
        "coverage_goal": daemon.config.coverage_goal,
        "verified_m2": report.verified_m2,
        "unverified_m2": report.unverified_m2,
        "unverified": report.unverified,
        "stop_threshold_m2": daemon.config.stop_threshold_m2,
        "collisions": collisions,
        "returned_home": report.returned_home,
        "exploration_s": report.exploration_s,
        "decisions": report.decisions,
        "waypoint_sources": report.waypoint_sources,
        "frames_fused": report.frames_fused,
        "frames_dropped": report.frames_dropped,
        "holds": report.holds,
        "decision_latency_ms": None if decision is None else {"p50": decision.p50_ms, "p95": decision.p95_ms},
        "decision_cpu_ms": None if decision_cpu is None else {"p50": decision_cpu.p50_ms, "p95": decision_cpu.p95_ms},
        "stages_ms": stages,
        "cpu": {
            "daemon_percent_of_one_core": 100 * daemon_cpu_s / report.wall_s,
            "process_percent_of_one_core": 100 * report.process_cpu_s / report.wall_s,
            "excluded_s": {
                "sim_vehicle_thread": vehicle_cpu_s,
                "depth_source": report.source_cpu_s if simulated else 0.0,
            },
            "depth_rate_hz": profile.rates_hz.depth,
            "load_average_1min": os.getloadavg()[0],
        },
        **memory_mb,  # peak RSS (the kernel's high-water mark) and the RSS at the end, split by resident_memory_mb
        "wall_s": report.wall_s,
        "timeline": report.timeline,
        "path_xy_m": report.path_xy_m,
    }


def explain_ending(report: Any, daemon: Any) -> dict[str, Any] | None:
    """Why the flight ended where it did (issue #18), like the benchmark's records: the goal, a time limit or a stop
    with the N_M area still unknown, or the planner finding nothing left while N_M cells were unknown (a planner
    stall), split into what the vehicle could have flown into and what it could only have seen from elsewhere.
    Without a plan: the map stop rule's ending, "map says verified", with the areas the maps believe verified and
    still unverified (issue #56); None for any other ending. Space no flight can reach or see is not in N_M
    (``plans check``)."""
    from edge_explorer.runtime.daemon.phases import MAP_STOP_ENDING  # here: draw_run's child imports this module

    truth, view = daemon.truth, daemon.view
    if truth is None and report.ending == MAP_STOP_ENDING and report.unverified_m2 is not None:
        text = (
            f"map says verified: {report.unverified_m2:.1f} m² unverified (below {daemon.config.stop_threshold_m2:g} "
            f"m²), {report.verified_m2:.1f} m² verified"
        )
        return {"reason": "map_verified", "text": text, "verified_m2": report.verified_m2, **(report.unverified or {})}
    if truth is None or view is None or report.coverage is None:
        return None
    known = view.thresholded if view.thresholded is not None else view.low
    unexplored, reachable = truth.unexplored(known, view.low_grid)
    cell_m2 = truth.grid.resolution_m**2
    figures = {
        "unexplored_m2": round(float(unexplored.sum() * cell_m2), 2),
        "unexplored_reachable_m2": round(float(reachable.sum() * cell_m2), 2),
    }
    left = f"{figures['unexplored_m2']:.1f} m² of N_M unknown ({figures['unexplored_reachable_m2']:.1f} m² reachable)"
    if report.coverage >= daemon.config.coverage_goal:
        return {"reason": "goal", "text": f"coverage {report.coverage:.1%}", **figures}
    if report.ending == "explored":
        text = f"planner stall: nothing left to explore in the observed map at {report.coverage:.1%}; {left}"
        return {"reason": "planner_stall", "text": text, **figures}
    return {"reason": report.ending, "text": f"{report.ending} at {report.coverage:.1%}; {left}", **figures}


def write_summary(out: Path, summary: dict[str, Any], daemon: Any, raster: Any) -> None:
    """``summary.json`` and ``summary.png`` in ``out``.

    The picture is drawn in a fresh interpreter (:func:`in_fresh_process`) from plain arrays: matplotlib and its
    figure (~65 MB resident) never load into the daemon's process, and the drawing process holds numpy and
    matplotlib only, not a copy of the daemon (a drone's daemon would not draw at all)."""
    from edge_explorer.cli_support import write_json

    write_json(out / "summary.json", summary)
    view = daemon.view
    if view is None:
        panels = [("no decision was taken: plan and path only", None, None)]
    else:
        panels = [("observed map (0.05 m) and path", view.high, view.high_grid)]
        if view.thresholded is not None:
            panels.append(("observed ∪ thresholded prediction (0.20 m)", view.thresholded, view.low_grid))
    plan = None if raster is None else (raster.occupied, raster.interior, raster.grid)
    unexplored = None
    if daemon.truth is not None and view is not None:
        known = view.thresholded if view.thresholded is not None else view.low
        unexplored = (daemon.truth.unexplored(known, view.low_grid)[0], daemon.truth.grid)
    in_fresh_process(draw_run, out / "summary.png", summary, panels, plan, daemon.home_xy_m, unexplored)


def in_fresh_process(function: Callable[..., object], *args: Any) -> None:
    """Run ``function(*args)`` in a new interpreter (multiprocessing's spawn: it imports ``function``'s module and
    unpickles the arguments, nothing else of this process) and wait for it. Raises :class:`RuntimeError` when the
    child fails (its traceback is on stderr)."""
    import multiprocessing

    child = multiprocessing.get_context("spawn").Process(target=function, args=args, name=function.__name__)
    child.start()
    child.join()
    if child.exitcode != 0:
        raise RuntimeError(f"{function.__name__} failed in its child process (exit code {child.exitcode})")


def print_summary(s: dict[str, Any]) -> None:
    """The run's one-line summary on stdout."""
    pct = lambda v: "–" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    latency = s["decision_latency_ms"] or {"p50": math.nan, "p95": math.nan}
    at_goal = "–" if s["path_at_goal_m"] is None else f"{s['path_at_goal_m']:.1f} m"
    print(
        f"run: {s['plan'] or 'no plan'}, {s['planner']} planner, ended by {s['ending']}{_why(s)}; "
        f"coverage {pct(s['coverage'])} "
        f"(correct {pct(s['correct_coverage'])}, observed {pct(s.get('observed_coverage'))}), "
        f"path {s['path_length_m']:.1f} m "
        f"(at {pct(s['coverage_goal'])}: {at_goal}), "
        f"map {_m2(s.get('verified_m2'))} verified, {_m2(s.get('unverified_m2'))} unverified, "
        f"collisions {s['collisions']}, decisions {s['decisions']}, decision latency p50 {latency['p50']:.1f} ms "
        f"p95 {latency['p95']:.1f} ms, CPU {s['cpu']['daemon_percent_of_one_core']:.1f} % of one core "
        f"(process {s['cpu']['process_percent_of_one_core']:.1f} %), peak RSS {s['peak_rss_mb']:.0f} MB"
        + _rss_split(s.get("rss_at_end_mb", {})),
        flush=True,
    )


def _m2(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f} m²"


def _why(s: dict[str, Any]) -> str:
    why = s.get("why")
    return "" if not why or why["reason"] == "goal" else f" ({why['text']})"


def _rss_split(rss_mb: dict[str, float]) -> str:
    if "anon" not in rss_mb or "file" not in rss_mb:
        return ""
    return f" (at the end {rss_mb['anon']:.0f} MB allocated + {rss_mb['file']:.0f} MB of mapped library pages)"


def draw_run(
    path: Path,
    summary: dict[str, Any],
    panels: list[tuple[str, Any, Any]],
    plan: tuple[Any, Any, Any] | None,
    home_xy: tuple[float, float] | None,
    unexplored: tuple[Any, Any] | None = None,
) -> None:
    """The run's picture: observed 0.05 m map and path over the true plan; beside it the thresholded prediction.

    ``panels``: (title, cell codes, their GridSpec) per panel, codes None for plan and path only (the run ended
    before its first decision); ``plan``: the true plan's (occupied, interior, GridSpec), None without a plan;
    ``unexplored``: (bool mask, its GridSpec) of the N_M cells still unknown at the end, hatched in orange.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from edge_explorer.world.grid import FREE, OCCUPIED

    fig, axes = plt.subplots(1, len(panels), figsize=(7 * len(panels), 5), squeeze=False)
    path_xy = np.asarray(summary["path_xy_m"], dtype=float).reshape(-1, 2)
    for ax, (title, codes, grid) in zip(axes[0], panels, strict=True):
        if plan is not None:
            occupied, interior, g = plan
            extent = (g.origin_xy[0], g.origin_xy[0] + g.size_xy_m[0], g.origin_xy[1], g.origin_xy[1] + g.size_xy_m[1])
            truth = np.where(occupied, 0.55, np.where(interior, 0.93, 1.0))
            ax.imshow(truth, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        if codes is not None:
            rgba = np.zeros((*codes.shape, 4))
            rgba[codes == FREE] = (0.55, 0.75, 1.0, 0.55)
            rgba[codes == OCCUPIED] = (0.05, 0.05, 0.05, 1.0)
            x0, y0 = grid.origin_xy
            ax.imshow(
                rgba,
                origin="lower",
                extent=(x0, x0 + grid.size_xy_m[0], y0, y0 + grid.size_xy_m[1]),
                interpolation="nearest",
            )
        if unexplored is not None and unexplored[0].any():
            mask, ug = unexplored
            rgba = np.zeros((*mask.shape, 4))
            rgba[mask] = (1.0, 0.5, 0.0, 0.8)
            x0, y0 = ug.origin_xy
            extent_u = (x0, x0 + ug.size_xy_m[0], y0, y0 + ug.size_xy_m[1])
            ax.imshow(rgba, origin="lower", extent=extent_u, interpolation="nearest")
        if len(path_xy):
            ax.plot(path_xy[:, 0], path_xy[:, 1], "-", color="tab:red", lw=1.2)
            ax.plot(*path_xy[-1], "o", color="tab:red", ms=5)
        if home_xy is not None:
            ax.plot(*home_xy, "s", color="tab:green", ms=6, label="home")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        if plan is not None:
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
    pct = lambda v: "–" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    fig.suptitle(
        f"{summary['plan'] or 'flight'} · {summary['planner']} · {summary['ending']} · coverage "
        f"{pct(summary['coverage'])} (correct {pct(summary['correct_coverage'])}) · path "
        f"{summary['path_length_m']:.1f} m · collisions {summary['collisions']}"
        + ("" if not summary.get("why") or summary["why"]["reason"] == "goal" else f"\n{summary['why']['text']}"),
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
