"""``edge-explorer run``: the on-device daemon, its acceptance bench (``--plans … --runs N``) and its soak
(``--soak 30m``).

With no arguments it flies the embedded default: bundled building A, the shipped models when present (else the
Nearest Frontier planner, said in the log), the ``host`` device profile, and the simulated PX4 vehicle with the
simulated depth camera over real MAVLink on loopback UDP. The vehicle starts where the exploration benchmark starts
on that building (:func:`edge_explorer.sim.starts.start_pose`), its odometry carries VIO-like noise and drift.

Outputs in ``--out`` (default ``runs/run-<timestamp>/``): ``summary.json`` (coverage, correct coverage, path
length, collisions, decisions, stage latency percentiles, CPU % of one core, peak RSS, backends), ``summary.png``
(the observed map, the prediction if any, and the path over the true plan), ``flight.tlog`` (every MAVLink message
both ways, readable by ``mavlogdump.py``) and ``daemon.log``.

The flight itself is :func:`edge_explorer.runtime.flight.fly`, the bench :mod:`edge_explorer.runtime.acceptance`, the
soak :mod:`edge_explorer.runtime.soak`; this module parses the arguments and hands them over, with the simulated
drone (:class:`edge_explorer.sim.flight.SimulatedFlight`) unless ``--connect`` names a real autopilot: then nothing of
the simulator is imported. SIGINT and SIGTERM stop
the flight with a hold setpoint, write the summary and close the telemetry log (exit code 130 after SIGINT, 0 after
SIGTERM: a requested, clean shutdown).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from edge_explorer.plan.registry import PLANNERS
from edge_explorer.runtime.options import MODELS_DIR, RunOptions
from edge_explorer.runtime.soak import parse_duration

if TYPE_CHECKING:
    from edge_explorer.runtime.flight import Simulation

DESCRIPTION = "The on-device exploration daemon: depth + odometry in, MAVLink position setpoints out."
EXIT_SIGINT = 130


def _positive(kind: type) -> Callable[[str], float]:
    """An argparse type: a finite number of ``kind`` (int or float) above zero."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            value = math.nan
        if not (value > 0 and math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}")
        return value

    return parse


def register(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser(
        "run", help="the exploration daemon (default: simulated drone in building A)", description=DESCRIPTION
    )
    run.add_argument(
        "--planner",
        choices=("auto", *PLANNERS),
        default="auto",
        help="; ".join(f"{name}: {entry.summary}" for name, entry in PLANNERS.items())
        + " (drl flies the shipped policy: an error if missing); auto (default): the policy when flight-ready, "
        "else frontier",
    )
    run.add_argument(
        "--profile",
        default="host",
        metavar="NAME|PATH",
        help="device profile: a name in profiles/ or a .toml (default host)",
    )
    run.add_argument(
        "--connect",
        metavar="URL",
        help="a real autopilot, e.g. udpin:0.0.0.0:14540 (default: the simulated vehicle on loopback UDP)",
    )
    run.add_argument(
        "--source", default="sim", metavar="SOURCE", help="depth frames: sim (default), replay:DIR, realsense"
    )
    where = run.add_mutually_exclusive_group()
    where.add_argument(
        "--plan",
        metavar="PLAN",
        help="the building: A-D, a plan .json or a map_server .yaml (default A; with "
        "--connect, optional: the plan of the real building, to measure coverage)",
    )
    where.add_argument(
        "--plans",
        metavar="LIST",
        help="acceptance bench: fly every building of this list (e.g. A,B,C,D) --runs times each, then print the table",
    )
    run.add_argument(
        "--soak",
        type=parse_duration,
        metavar="DURATION",
        help="fly the simulated drone's flights back to back in one process for DURATION (e.g. 30m), reporting RSS "
        "over time, decisions, holds and collisions (soak.json, soak.png in --out)",
    )
    run.add_argument(
        "--runs", type=_positive(int), default=1, metavar="N", help="with --plans: flights per building (default 1)"
    )
    run.add_argument("--json", type=Path, metavar="PATH", help="with --plans: write the bench figures here")
    run.add_argument("--markdown", type=Path, metavar="PATH", help="with --plans: the bench as a Markdown page")
    run.add_argument("--plot", type=Path, metavar="PATH", help="with --plans: the bench's figure (PNG)")
    run.add_argument(
        "--compare",
        type=Path,
        metavar="PATH",
        help="with --plans: `bench explore` JSON whose frontier paths the daemon's are compared with "
        "(default docs/bench/bundled.json)",
    )
    run.add_argument(
        "--time-limit-s",
        type=_positive(float),
        metavar="S",
        help="flight budget after take-off: exploration ends early enough to be home within it (default: "
        "DaemonConfig.time_limit_s, 10 min; with --plans 20 min)",
    )
    run.add_argument("--no-return", action="store_true", help="hover where exploration ends instead of flying home")
    run.add_argument("--out", type=Path, metavar="DIR", help="output folder (default runs/run-<timestamp>/)")
    run.add_argument(
        "--seed",
        type=int,
        default=0,
        metavar="N",
        help="start pose and noise seed, as the exploration benchmark's --seed (default 0)",
    )
    run.add_argument(
        "--run-index",
        type=int,
        default=0,
        metavar="K",
        help="fly the benchmark's run K of the building: its noise seed (default 0)",
    )
    run.add_argument(
        "--models", type=Path, default=MODELS_DIR, metavar="DIR", help=f"model folder (default {MODELS_DIR})"
    )
    run.add_argument(
        "--record", type=Path, metavar="DIR", help="record every fused frame and its pose here (for --source replay:)"
    )
    run.add_argument(
        "--autopilot",
        choices=("px4", "ardupilot"),
        default="px4",
        help="start sequence: PX4 OFFBOARD (default) or ArduPilot GUIDED",
    )
    run.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.runtime.flight import fly

    out = args.out or Path("runs") / time.strftime("run-%Y%m%d-%H%M%S")
    _log_to_stderr()
    if args.connect is not None and args.source == "sim":
        raise EdgeExplorerError(
            "--source sim renders from the simulated vehicle: without it (--connect) use --source realsense or "
            "--source replay:DIR"
        )
    if args.connect is None and args.source == "realsense":
        raise EdgeExplorerError("--source realsense is the camera of a real drone: give its autopilot with --connect")
    options = RunOptions(
        out_dir=out,
        planner=args.planner,
        profile=args.profile,
        connect=args.connect,
        source=args.source,
        plan=args.plan if args.plan is not None or args.connect is not None else "A",
        time_limit_s=args.time_limit_s,
        return_home=not args.no_return,
        seed=args.seed,
        run_index=args.run_index,
        models_dir=args.models,
        record_dir=args.record,
        autopilot=args.autopilot,
    )
    if args.plans is not None and args.soak is not None:
        raise EdgeExplorerError("--plans runs the acceptance bench, --soak the soak: choose one")
    if args.plans is not None:
        if args.connect is not None or args.source != "sim" or args.record is not None:
            raise EdgeExplorerError("--plans flies the simulated drone: drop --connect, --source and --record")
        from edge_explorer.runtime.acceptance import run_acceptance

        return run_acceptance(options, args.plans, args.runs, args.json, args.markdown, args.plot, args.compare)
    if args.soak is not None:
        if args.connect is not None or args.source != "sim" or args.record is not None:
            raise EdgeExplorerError("--soak flies the simulated drone: drop --connect, --source and --record")
        from edge_explorer.runtime.soak import run_soak

        return run_soak(options, args.soak, simulation=_simulation())
    summary = fly(options, _simulation() if args.connect is None else None)
    print(f"summary: {out / 'summary.json'}, {out / 'summary.png'}")
    return EXIT_SIGINT if summary["ending"] == "interrupted (SIGINT)" else 0


def _simulation() -> Simulation:
    """The simulated drone (vehicle, depth camera, start pose) a flight without ``--connect`` flies; only then is the
    simulator imported."""
    from edge_explorer.sim.flight import SimulatedFlight

    return SimulatedFlight()


def _log_to_stderr() -> None:
    """INFO and above to stderr, once per process."""
    root = logging.getLogger()
    if not any(getattr(h, "edge_explorer_run", False) for h in root.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
        handler.edge_explorer_run = True  # type: ignore[attr-defined]
        root.addHandler(handler)
    root.setLevel(logging.INFO)
