"""One flight of ``edge-explorer run``: the flight API that the command line and the acceptance bench share.

:class:`RunOptions` holds one flight's arguments; :func:`fly` sets the flight up (device profile, building, models,
the simulated vehicle and depth camera or a real autopilot and camera), runs the :class:`~edge_explorer.runtime.
daemon.Daemon` under SIGINT/SIGTERM handlers that stop it with a hold setpoint, and writes the outputs
(:mod:`edge_explorer.runtime.flight_summary`). The vehicle starts where the exploration benchmark starts on that
building (:func:`edge_explorer.sim.starts.start_pose`), its odometry carries VIO-like noise.

CPU: the daemon's share is the process's CPU time minus what belongs to the simulated world — the vehicle's
physics thread and the depth renderer (the camera's work on a real drone) — over the run's wall time; the process
total is reported beside it.
"""

from __future__ import annotations

import logging
import os
import resource
import signal
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from edge_explorer.runtime.options import RunOptions

log = logging.getLogger(__name__)


def fly(options: RunOptions) -> dict[str, Any]:
    """Fly one run as ``edge-explorer run`` does and write its outputs; returns the summary (also in JSON)."""
    from contextlib import ExitStack

    from edge_explorer.profiling.device_profile import load_profile
    from edge_explorer.runtime.kernels import kernels_warm, release_llvm_pages, warm_kernels
    from edge_explorer.world.catalog import load_building

    out = options.out_dir
    out.mkdir(parents=True, exist_ok=True)
    file_log = logging.FileHandler(out / "daemon.log", mode="w")
    file_log.setFormatter(logging.Formatter("%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
    logging.getLogger().addHandler(file_log)
    try:
        profile = load_profile(options.profile)
        raster = load_building(options.plan) if options.plan is not None else None
        start = None
        if options.connect is None:
            if raster is None:
                raise ValueError("the simulated vehicle needs a plan")
            start = _start_pose(options.plan, options.seed)
        if raster is not None:
            # Before the flight's other imports: the flight's numba kernels compiled in a child (on a fresh install)
            # and loaded here, then LLVM's pages handed back (runtime/kernels.py).
            if not kernels_warm():
                _compile_kernels(raster)
                warm_kernels(raster)
            log.info("numba kernels loaded; %.1f MB of LLVM's pages released", release_llvm_pages())

        from edge_explorer.bench.explore import run_seed
        from edge_explorer.mapping.voxels import VoxelRegion
        from edge_explorer.plan.registry import PLANNERS
        from edge_explorer.runtime.daemon import CoverageTruth, Daemon, DaemonConfig, band_z_range_m, choose_models
        from edge_explorer.runtime.depth_sources import Recorder
        from edge_explorer.runtime.flight_summary import print_summary, run_summary, write_summary
        from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink
        from edge_explorer.sim.vehicle import THREAD_NAME as SIM_VEHICLE_THREAD

        noise_seed = run_seed(options.seed, raster.name, options.run_index) if raster is not None else options.seed
        models = choose_models(
            options.models_dir, options.planner, profile.backend_order, model_orders=profile.model_orders
        )
        for note in models.notes:
            log.info(note)
        setpoint_rate_hz = max(profile.rates_hz.setpoint, 10.0)
        entry = PLANNERS.get(options.planner)  # auto and drl: frontier explores when no policy flies
        explorer = options.planner if entry is not None and not entry.needs_policy else "frontier"
        config = DaemonConfig(
            return_home=options.return_home,
            autopilot=options.autopilot,
            setpoint_rate_hz=setpoint_rate_hz,
            decision_lead_s=1.0 / profile.rates_hz.depth,
            exploration_planner=explorer,
        )
        if models.predictor is not None:  # its card's calibrated thresholds win over the defaults (docs/design.md §5)
            config = replace(config, thresholds=models.predictor.thresholds)
        if options.time_limit_s is not None:
            config = replace(config, time_limit_s=options.time_limit_s)
        with ExitStack() as stack:
            vehicle = None
            if options.connect is None:
                assert raster is not None and start is not None
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
                report = daemon.run(_progress_printer(models, config.exploration_planner) if options.progress else None)
            vehicle_cpu_s = thread_cpu_s(SIM_VEHICLE_THREAD) - vehicle_cpu0
            collisions = vehicle.state().collisions if vehicle is not None else None
            peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            rss_now_mb = resident_memory_mb()
        # The start pose's and the kernel compiler's processes (the largest of them; the picture's comes later).
        children_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        memory_mb = {"peak_rss_mb": peak_rss_mb, "rss_at_end_mb": rss_now_mb, "children_peak_rss_mb": children_mb}
        summary = run_summary(
            options, profile, models, raster, start, noise_seed, report, collisions, vehicle_cpu_s, memory_mb, daemon
        )
        write_summary(out, summary, daemon, raster)
        print_summary(summary)
        return summary
    finally:
        logging.getLogger().removeHandler(file_log)
        file_log.close()


def _start_pose(plan: str, seed: int) -> tuple[float, float, float]:
    """The exploration benchmark's start pose on ``plan`` (:func:`edge_explorer.sim.starts.start_pose`), drawn in
    a new interpreter with numba's JIT off. The draw builds the training simulator (~50 MB) and resets it, which
    would compile a dozen numba kernels (LLVM's code and working memory: ~120 MB on a fresh install) whose results
    the pose does not depend on: the pose is drawn from the seeded generator and checked against the plan's
    clearance before the simulator's sensor runs. Interpreted, the draw takes ~0.4 s and ~180 MB, none of it in the
    flight's process (tests/runtime/test_kernels.py checks the pose is the same)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=spawn, initializer=_numba_jit_off) as pool:
        return pool.submit(_draw_start_pose, plan, seed).result()


def _numba_jit_off() -> None:
    """In the start pose's interpreter, before numba's import: njit functions stay plain Python functions, and the
    LLVM pages numba's import maps (~90 MB on a fresh install) are handed back at once, as nothing compiles."""
    os.environ["NUMBA_DISABLE_JIT"] = "1"
    import numba  # noqa: F401

    from edge_explorer.runtime.kernels import release_llvm_pages

    release_llvm_pages()


def _draw_start_pose(plan: str, seed: int) -> tuple[float, float, float]:
    """The start pose's child's work. Where numba's JIT is on (any caller but :func:`_start_pose`'s interpreter),
    the flight's kernels run first (:func:`~edge_explorer.runtime.kernels.warm_kernels`, then LLVM's pages are
    released), so that one call fills numba's cache for a whole flight."""
    import numba

    from edge_explorer.world.catalog import load_building

    raster = load_building(plan)
    if not numba.config.DISABLE_JIT:
        from edge_explorer.runtime.kernels import release_llvm_pages, warm_kernels

        warm_kernels(raster)
        release_llvm_pages()

    from edge_explorer.bench.explore import start_pose

    x_m, y_m, yaw_rad = start_pose(raster, seed)
    return float(x_m), float(y_m), float(yaw_rad)


def _compile_kernels(raster: Any) -> None:
    """:func:`~edge_explorer.runtime.kernels.warm_kernels` in a forked child process: on a fresh install numba
    compiles the flight's kernels there (LLVM's code and working memory, ~100 MB, and ~2 s) into its on-disk
    cache, so the flight's process only loads them — as on a drone whose install step compiled them. Forked before
    the flight's heavier imports (pymavlink, LiteRT, the planners), so the child holds little else."""
    import multiprocessing

    from edge_explorer.runtime.kernels import warm_kernels

    child = multiprocessing.get_context("fork").Process(target=warm_kernels, args=(raster,), name="compile-kernels")
    child.start()
    child.join()
    if child.exitcode != 0:
        raise RuntimeError(f"compiling the flight's numba kernels failed (exit code {child.exitcode})")


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
    from edge_explorer.sim.camera import DepthCamera
    from edge_explorer.vehicle.camera import CameraPose

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


def _progress_printer(models: Any, exploration_planner: str) -> Callable[[Any], None]:
    """Prints one progress line: coverage, path, decision latency, the planner and where the models run."""
    policy = exploration_planner if models.policy is None else f"drl on {models.policy.model.backend.name}"
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
