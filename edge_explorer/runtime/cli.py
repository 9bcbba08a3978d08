"""``edge-explorer run``: the on-device daemon, and its acceptance bench (``--plans … --runs N``).

With no arguments it flies the embedded default: bundled building A, the shipped models when present (else the
Nearest Frontier planner, said in the log), the ``host`` device profile, and the simulated PX4 vehicle with the
simulated depth camera over real MAVLink on loopback UDP. The vehicle starts where the exploration benchmark starts
on that building (:func:`edge_explorer.bench.explore.start_pose`), its odometry carries VIO-like noise and drift.

Outputs in ``--out`` (default ``runs/run-<timestamp>/``): ``summary.json`` (coverage, correct coverage, path
length, collisions, decisions, stage latency percentiles, CPU % of one core, peak RSS, backends), ``summary.png``
(the observed map, the prediction if any, and the path over the true plan), ``flight.tlog`` (every MAVLink message
both ways, readable by ``mavlogdump.py``) and ``daemon.log``.

CPU: the daemon's share is the process's CPU time minus what belongs to the simulated world — the vehicle's
physics thread and the depth renderer (the camera's work on a real drone) — over the run's wall time; the process
total is reported beside it. SIGINT and SIGTERM stop the flight with a hold setpoint, write the summary and close
the telemetry log (exit code 130 after SIGINT, 0 after SIGTERM: a requested, clean shutdown).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import resource
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

DESCRIPTION = "The on-device exploration daemon: depth + odometry in, MAVLink position setpoints out."
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
EXIT_SIGINT = 130

log = logging.getLogger(__name__)


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
        choices=("auto", "drl", "frontier"),
        default="auto",
        help="drl: the shipped policy (an error if missing); frontier: Nearest Frontier; auto (default): "
        "the policy when shipped, else frontier",
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
        help="exploration time before flying home (default: DaemonConfig.time_limit_s, 10 min; with --plans 20 min)",
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


@dataclass(frozen=True)
class RunOptions:
    """One flight of ``edge-explorer run`` (the command's arguments)."""

    out_dir: Path
    planner: str = "auto"
    profile: str = "host"
    connect: str | None = None
    source: str = "sim"
    plan: str | None = "A"
    time_limit_s: float | None = None  # None: DaemonConfig's
    return_home: bool = True
    seed: int = 0
    run_index: int = 0  # the run's noise seed is the benchmark's run_seed(seed, plan, run_index)
    models_dir: Path = MODELS_DIR
    record_dir: Path | None = None
    autopilot: str = "px4"
    progress: bool = True


def _run(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError

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
    if args.plans is not None:
        if args.connect is not None or args.source != "sim" or args.record is not None:
            raise EdgeExplorerError("--plans flies the simulated drone: drop --connect, --source and --record")
        from edge_explorer.runtime.acceptance import run_acceptance

        return run_acceptance(options, args.plans, args.runs, args.json, args.markdown, args.plot, args.compare)
    summary = fly(options)
    print(f"summary: {out / 'summary.json'}, {out / 'summary.png'}")
    return EXIT_SIGINT if summary["ending"] == "interrupted (SIGINT)" else 0


def _log_to_stderr() -> None:
    """INFO and above to stderr, once per process."""
    root = logging.getLogger()
    if not any(getattr(h, "edge_explorer_run", False) for h in root.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
        handler.edge_explorer_run = True  # type: ignore[attr-defined]
        root.addHandler(handler)
    root.setLevel(logging.INFO)


# ---------------------------------------------------------------------------------------------------------------
# One flight
# ---------------------------------------------------------------------------------------------------------------


def fly(options: RunOptions) -> dict[str, Any]:
    """Fly one run as ``edge-explorer run`` does and write its outputs; returns the summary (also in JSON)."""
    from contextlib import ExitStack

    from edge_explorer.bench.explore import run_seed
    from edge_explorer.mapping.voxels import VoxelRegion
    from edge_explorer.profiling.device_profile import load_profile
    from edge_explorer.runtime.daemon import CoverageTruth, Daemon, DaemonConfig, band_z_range_m, choose_models
    from edge_explorer.runtime.depth_sources import Recorder
    from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink
    from edge_explorer.sim.vehicle import THREAD_NAME as SIM_VEHICLE_THREAD
    from edge_explorer.world.catalog import load_building

    out = options.out_dir
    out.mkdir(parents=True, exist_ok=True)
    file_log = logging.FileHandler(out / "daemon.log", mode="w")
    file_log.setFormatter(logging.Formatter("%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
    logging.getLogger().addHandler(file_log)
    try:
        profile = load_profile(options.profile)
        raster = load_building(options.plan) if options.plan is not None else None
        noise_seed = run_seed(options.seed, raster.name, options.run_index) if raster is not None else options.seed
        models = choose_models(
            options.models_dir, options.planner, profile.backend_order, model_orders=profile.model_orders
        )
        for note in models.notes:
            log.info(note)
        setpoint_rate_hz = max(profile.rates_hz.setpoint, 10.0)
        config = DaemonConfig(
            return_home=options.return_home,
            autopilot=options.autopilot,
            setpoint_rate_hz=setpoint_rate_hz,
            decision_lead_s=1.0 / profile.rates_hz.depth,
        )
        if options.time_limit_s is not None:
            config = replace(config, time_limit_s=options.time_limit_s)
        with ExitStack() as stack:
            start = None
            vehicle = None
            if options.connect is None:
                if raster is None:
                    raise ValueError("the simulated vehicle needs a plan")
                start = _start_pose(options.plan, options.seed)
                vehicle = stack.enter_context(_simulated_vehicle(raster, start, noise_seed, options.autopilot))
                connect = f"udpout:127.0.0.1:{vehicle.address[1]}"
            else:
                connect = options.connect
            link_config = LinkConfig(connect=connect, setpoint_rate_hz=setpoint_rate_hz, tlog_path=out / "flight.tlog")
            link = stack.enter_context(MavlinkLink(link_config))
            source = _depth_source(options.source, raster, vehicle, profile.rates_hz.depth, noise_seed)
            stack.callback(source.close)
            recorder = None
            if options.record_dir is not None:
                recorder = stack.enter_context(Recorder(options.record_dir, source.intrinsics))
            daemon = Daemon(
                config,
                link,
                source,
                models.policy,
                models.predictor,
                truth=CoverageTruth(raster) if raster is not None else None,
                region=VoxelRegion.covering(raster.grid, *band_z_range_m(config.band)) if raster is not None else None,
                recorder=recorder,
            )
            vehicle_cpu0 = thread_cpu_s(SIM_VEHICLE_THREAD)
            with _stop_on_signals(daemon):
                report = daemon.run(_progress_printer(models) if options.progress else None)
            vehicle_cpu_s = thread_cpu_s(SIM_VEHICLE_THREAD) - vehicle_cpu0
            collisions = vehicle.state().collisions if vehicle is not None else None
            peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            rss_now_mb = resident_memory_mb()
        memory_mb = {"peak_rss_mb": peak_rss_mb, "rss_at_end_mb": rss_now_mb}
        summary = _summary(
            options, profile, models, raster, start, noise_seed, report, collisions, vehicle_cpu_s, memory_mb, daemon
        )
        _write_summary(out, summary, daemon, raster)
        _print_summary(summary)
        return summary
    finally:
        logging.getLogger().removeHandler(file_log)
        file_log.close()


def _start_pose(plan: str, seed: int) -> tuple[float, float, float]:
    """The exploration benchmark's start pose on ``plan`` (:func:`edge_explorer.bench.explore.start_pose`), drawn in
    a forked child process that also renders one depth frame there and runs the daemon's mapping kernels on it. None
    of this belongs to the flight whose peak RSS the run reports: the draw builds the training simulator (~50 MB),
    and on a fresh clone the first render and the first fused frame compile numba kernels (~30 MB of LLVM and half a
    second of the first decisions). The child writes them to numba's on-disk cache, so the daemon only loads them —
    as on a drone whose install step compiled them."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork")) as pool:
        return pool.submit(_draw_start_pose, plan, seed).result()


def _draw_start_pose(plan: str, seed: int) -> tuple[float, float, float]:
    from edge_explorer.bench.explore import start_pose
    from edge_explorer.sim.camera import CameraPose, DepthCamera
    from edge_explorer.world.catalog import load_building

    raster = load_building(plan)
    x_m, y_m, yaw_rad = start_pose(raster, seed)
    camera = DepthCamera(raster)
    pose = CameraPose(float(x_m), float(y_m), 1.7, float(yaw_rad))
    _compile_daemon_kernels(raster, camera.config.intrinsics, pose, camera.render(pose))
    return float(x_m), float(y_m), float(yaw_rad)


def _compile_daemon_kernels(raster: Any, intrinsics: Any, pose: Any, depth_m: Any) -> None:
    """Call each numba kernel of the daemon's loop once, with the loop's argument types, on one rendered frame:
    fusion, projection, the coverage count and the follower's swept-path test (numba caches one machine-code
    version per argument types, so these calls fill the cache the flight loads from)."""
    import numpy as np

    from edge_explorer.mapping.projection import project
    from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
    from edge_explorer.runtime.daemon import CoverageTruth, DaemonConfig, band_z_range_m
    from edge_explorer.sim.dynamics import swept_path_blocked

    config = DaemonConfig()
    maps = VoxelMaps(VoxelRegion.covering(raster.grid, *band_z_range_m(config.band)), config.fusion)
    maps.fuse(depth_m, intrinsics, pose.position_m, pose.rotation_map_from_optical(), 0.0)
    high, high_grid = project(maps.high, config.band)
    low, low_grid = project(maps.low, config.band)
    CoverageTruth(raster).metrics(low, low_grid, None)
    swept_path_blocked(np.zeros(high.shape, dtype=bool), high_grid, (pose.x_m, pose.y_m), (pose.x_m, pose.y_m))


def _simulated_vehicle(raster: Any, start: tuple[float, float, float], noise_seed: int, flavour: str) -> Any:
    from edge_explorer.sim.vehicle import OdometryNoise, SimulatedVehicle, VehicleConfig

    # White odometry noise only: the simulated vehicle flies its true position to the setpoint while it reports the
    # drifted one, whereas a real autopilot flies its own (drifting) estimate; with drift on, every hold at the
    # reported pose would creep by the drift.
    noise = OdometryNoise(position_drift_m_per_sqrt_s=0.0, yaw_drift_rad_per_sqrt_s=0.0, seed=noise_seed)
    config = VehicleConfig(
        connect="udpin:127.0.0.1:0",
        flavour=flavour,
        start_xyz_m=(start[0], start[1], 0.0),
        start_yaw_rad=start[2],
        odometry_noise=noise,
    )
    return SimulatedVehicle(config, raster)


def _depth_source(spec: str, raster: Any, vehicle: Any, rate_hz: float, noise_seed: int) -> Any:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.runtime.depth_sources import RealSenseDepthSource, ReplayDepthSource, SimulatedDepthSource
    from edge_explorer.sim.camera import CameraPose, DepthCamera

    if spec == "sim":
        camera = DepthCamera(raster)
        truth = vehicle.true_pose()
        camera.render(CameraPose(truth.x_m, truth.y_m, 1.7, truth.yaw_rad))  # load the renderer before the flight
        return SimulatedDepthSource(camera, vehicle, rate_hz=rate_hz, seed=noise_seed)
    if spec.startswith("replay:"):
        return ReplayDepthSource(Path(spec.removeprefix("replay:")), realtime=True)
    if spec == "realsense":
        return RealSenseDepthSource(fps=int(round(rate_hz)))
    raise EdgeExplorerError(f"--source {spec!r}: use sim, replay:DIR or realsense")


class _stop_on_signals:
    """SIGINT and SIGTERM ask the daemon to stop (main thread only; elsewhere signals keep their handlers)."""

    def __init__(self, daemon: Any) -> None:
        self._daemon = daemon
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig, name in ((signal.SIGINT, "SIGINT"), (signal.SIGTERM, "SIGTERM")):
            self._previous[sig] = signal.signal(sig, lambda *_, n=name: self._daemon.request_stop(f"interrupted ({n})"))

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def thread_cpu_s(name: str) -> float:
    """CPU seconds of the live thread called ``name`` (Linux /proc); 0 if there is none."""
    for thread in threading.enumerate():
        if thread.name == name and thread.native_id is not None:
            try:
                fields = Path(f"/proc/self/task/{thread.native_id}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                return 0.0
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return 0.0


def resident_memory_mb() -> dict[str, float]:
    """This process's resident memory now, split as Linux counts it (``/proc/self/status``): ``anon`` is what the
    process allocated (heap, arrays, numba's machine code), ``file`` the mapped pages of files — the shared
    libraries — which are page cache, shared with other processes and reclaimable. ``file`` depends on the page
    cache as well as on the process: a library pip has just written is cached in large folios that a page fault maps
    whole, so right after a fresh install the same daemon counts ~80 MB more (docs/runtime/README.md, "Memory")."""
    fields = {"RssAnon": "anon", "RssFile": "file", "RssShmem": "shmem"}
    found: dict[str, float] = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in fields:
            found[fields[key]] = int(value.split()[0]) / 1024  # kB
    return found


def _progress_printer(models: Any) -> Callable[[Any], None]:
    """Prints one progress line: coverage, path, decision latency, where the models run."""
    policy = "frontier" if models.policy is None else f"drl on {models.policy.model.backend.name}"
    predictor = "none" if models.predictor is None else models.predictor.model.backend.name
    backends = f"planner {policy}, predictor {predictor}"

    def show(p: Any) -> None:
        cov = "coverage   –  " if p.coverage is None else f"coverage {100 * p.coverage:5.1f} %"
        if p.correct_coverage is not None:
            cov += f" (correct {100 * p.correct_coverage:5.1f} %)"
        latency = "–" if p.decision_p95_ms is None else f"{p.decision_p95_ms:.1f} ms"
        line = (
            f"{p.elapsed_s:6.1f} s  {p.phase:<9}  {cov}  path {p.path_length_m:6.1f} m  decisions "
            f"{p.decisions:4d}  decision p95 {latency}  {backends}"
        )
        if p.holding:
            line += f"  HOLDING: {p.holding}"
        print(line, flush=True)

    return show


# ---------------------------------------------------------------------------------------------------------------
# The run summary
# ---------------------------------------------------------------------------------------------------------------


def _summary(
    options: RunOptions,
    profile: Any,
    models: Any,
    raster: Any,
    start: tuple[float, float, float] | None,
    noise_seed: int,
    report: Any,
    collisions: int | None,
    vehicle_cpu_s: float,
    memory_mb: dict[str, Any],
    daemon: Any,
) -> dict[str, Any]:
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
        "models": list(models.notes),
        "backends": {
            "policy": None if models.policy is None else models.policy.model.backend.name,
            "predictor": None if models.predictor is None else models.predictor.model.backend.name,
        },
        "ending": report.ending,
        "coverage": report.coverage,
        "correct_coverage": report.correct_coverage,
        "f1": report.f1,
        "path_length_m": report.path_length_m,
        "path_at_goal_m": report.path_at_goal_m,
        "coverage_goal": daemon.config.coverage_goal,
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


def _write_summary(out: Path, summary: dict[str, Any], daemon: Any, raster: Any) -> None:
    from edge_explorer.cli import write_json

    write_json(out / "summary.json", summary)
    draw_run(out / "summary.png", summary, daemon.view, raster, daemon.home_xy_m)


def _print_summary(s: dict[str, Any]) -> None:
    pct = lambda v: "–" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    latency = s["decision_latency_ms"] or {"p50": math.nan, "p95": math.nan}
    at_goal = "–" if s["path_at_goal_m"] is None else f"{s['path_at_goal_m']:.1f} m"
    print(
        f"run: {s['plan'] or 'no plan'}, {s['planner']} planner, ended by {s['ending']}; coverage {pct(s['coverage'])} "
        f"(correct {pct(s['correct_coverage'])}), path {s['path_length_m']:.1f} m "
        f"(at {pct(s['coverage_goal'])}: {at_goal}), "
        f"collisions {s['collisions']}, decisions {s['decisions']}, decision latency p50 {latency['p50']:.1f} ms "
        f"p95 {latency['p95']:.1f} ms, CPU {s['cpu']['daemon_percent_of_one_core']:.1f} % of one core "
        f"(process {s['cpu']['process_percent_of_one_core']:.1f} %), peak RSS {s['peak_rss_mb']:.0f} MB"
        + _rss_split(s.get("rss_at_end_mb", {})),
        flush=True,
    )


def _rss_split(rss_mb: dict[str, float]) -> str:
    if "anon" not in rss_mb or "file" not in rss_mb:
        return ""
    return f" (at the end {rss_mb['anon']:.0f} MB allocated + {rss_mb['file']:.0f} MB of mapped library pages)"


def draw_run(path: Path, summary: dict[str, Any], view: Any, raster: Any, home_xy: tuple[float, float] | None) -> None:
    """The run's picture: observed 0.05 m map and path over the true plan; beside it the thresholded prediction.

    ``view`` is the last decision's maps (None when the run ended before its first decision: plan and path only).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from edge_explorer.world.grid import FREE, OCCUPIED

    if view is None:
        panels = [("no decision was taken: plan and path only", None, None)]
    else:
        panels = [("observed map (0.05 m) and path", view.high, view.high_grid)]
    if view is not None and view.thresholded is not None:
        panels.append(("observed ∪ thresholded prediction (0.20 m)", view.thresholded, view.low_grid))
    fig, axes = plt.subplots(1, len(panels), figsize=(7 * len(panels), 5), squeeze=False)
    path_xy = np.asarray(summary["path_xy_m"], dtype=float).reshape(-1, 2)
    for ax, (title, codes, grid) in zip(axes[0], panels, strict=True):
        if raster is not None:
            g = raster.grid
            extent = (g.origin_xy[0], g.origin_xy[0] + g.size_xy_m[0], g.origin_xy[1], g.origin_xy[1] + g.size_xy_m[1])
            truth = np.where(raster.occupied, 0.55, np.where(raster.interior, 0.93, 1.0))
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
        if len(path_xy):
            ax.plot(path_xy[:, 0], path_xy[:, 1], "-", color="tab:red", lw=1.2)
            ax.plot(*path_xy[-1], "o", color="tab:red", ms=5)
        if home_xy is not None:
            ax.plot(*home_xy, "s", color="tab:green", ms=6, label="home")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        if raster is not None:
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
    pct = lambda v: "–" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    fig.suptitle(
        f"{summary['plan'] or 'flight'} · {summary['planner']} · {summary['ending']} · coverage "
        f"{pct(summary['coverage'])} (correct {pct(summary['correct_coverage'])}) · path "
        f"{summary['path_length_m']:.1f} m · collisions {summary['collisions']}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
