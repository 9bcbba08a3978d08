"""One flight of ``edge-explorer run``: the flight API that the command line and the acceptance bench share.

:class:`RunOptions` holds one flight's arguments; :func:`fly` sets the flight up (device profile, building, models,
the simulated vehicle and depth camera or a real autopilot and camera), runs the :class:`~edge_explorer.runtime.
daemon.Daemon` under SIGINT/SIGTERM handlers that stop it with a hold setpoint, and writes the outputs
(:mod:`edge_explorer.runtime.flight_summary`). The simulated vehicle and camera come from the caller
(:class:`Simulation`, built by :mod:`edge_explorer.sim.flight`): the vehicle starts where the exploration benchmark
starts on that building (:func:`edge_explorer.sim.starts.start_pose`), its odometry carries VIO-like noise.

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
from typing import TYPE_CHECKING, Any, Protocol

from edge_explorer.runtime.options import RunOptions

if TYPE_CHECKING:
    from edge_explorer.runtime.depth_sources import DepthSource

log = logging.getLogger(__name__)


class Simulation(Protocol):
    """The simulated world a flight without ``--connect`` flies in (:class:`edge_explorer.sim.flight.SimulatedFlight`;
    the command line builds it, so that a flight with a real autopilot never imports the simulator)."""

    @property
    def vehicle_thread(self) -> str:
        """The simulated vehicle's physics thread, whose CPU time is metered apart from the daemon's."""
        ...

    def camera(self, raster: Any) -> Any:
        """The depth renderer of ``raster``: its kernel is loaded with the flight's (``warm_kernels``)."""
        ...

    def start_pose(self, raster: Any, seed: int) -> tuple[float, float, float]: ...

    def vehicle(self, raster: Any, start: tuple[float, float, float], noise_seed: int, flavour: str) -> Any: ...

    def depth_source(self, raster: Any, vehicle: Any, rate_hz: float, noise_seed: int) -> DepthSource: ...


def fly(options: RunOptions, simulation: Simulation | None = None) -> dict[str, Any]:
    """Fly one run as ``edge-explorer run`` does and write its outputs; returns the summary (also in JSON).

    Without ``options.connect`` the flight needs ``simulation`` (the simulated vehicle and depth camera,
    :class:`edge_explorer.sim.flight.SimulatedFlight`), which the caller builds: this module imports nothing of the
    simulator."""
    from contextlib import ExitStack

    from edge_explorer.runtime.device_profile import load_profile
    from edge_explorer.runtime.heap import bound_heap, trim_heap
    from edge_explorer.runtime.kernels import kernels_warm, release_llvm_pages, warm_kernels
    from edge_explorer.world.catalog import load_building

    bound_heap()  # large arrays go back to the system when freed (runtime/heap.py)
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
            if simulation is None:
                raise ValueError("without --connect the flight needs the simulated vehicle (edge_explorer.sim.flight)")
            start = simulation.start_pose(raster, options.seed)
        if raster is not None:
            # Before the flight's other imports: the flight's numba kernels compiled in a child (on a fresh install)
            # and loaded here, then LLVM's pages handed back (runtime/kernels.py).
            camera = simulation.camera if simulation is not None else None
            if not kernels_warm():
                _compile_kernels(raster, camera)
                warm_kernels(raster, camera)
            log.info("numba kernels loaded; %.1f MB of LLVM's pages released", release_llvm_pages())

        from edge_explorer.plan.registry import PLANNERS
        from edge_explorer.runtime.daemon import CoverageTruth, Daemon, DaemonConfig, choose_models
        from edge_explorer.runtime.depth_sources import Recorder
        from edge_explorer.runtime.flight_summary import print_summary, run_summary, write_summary
        from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink
        from edge_explorer.world.seeds import run_seed

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
                assert simulation is not None
                vehicle = stack.enter_context(simulation.vehicle(raster, start, noise_seed, options.autopilot))
                connect = f"udpout:127.0.0.1:{vehicle.address[1]}"
            else:
                connect = options.connect
            link_config = LinkConfig(connect=connect, setpoint_rate_hz=setpoint_rate_hz, tlog_path=out / "flight.tlog")
            link = stack.enter_context(MavlinkLink(link_config))
            source = _depth_source(options.source, raster, vehicle, profile.rates_hz.depth, noise_seed, simulation)
            stack.callback(source.close)
            recorder = None
            if options.record_dir is not None:
                recorder = stack.enter_context(Recorder(options.record_dir, source.intrinsics))
            printer = _progress_printer(models, config.exploration_planner) if options.progress else None
            model_notes, backends = models.notes, models.backends()
            daemon = Daemon(
                config,
                link,
                source,
                models.policy,
                models.predictor,
                truth=CoverageTruth(raster) if raster is not None else None,
                recorder=recorder,
            )
            # The daemon holds the models alone from here, so it can release the shipped predictor's interpreter
            # once the whole-floor one has taken over (the summary keeps only their names).
            del models
            vehicle_thread = simulation.vehicle_thread if simulation is not None else None
            vehicle_cpu0 = thread_cpu_s(vehicle_thread) if vehicle_thread is not None else 0.0
            trim_heap()  # the set-up's transients (the plan's loading, the models' warm-up) are gone by now
            with _stop_on_signals(daemon):
                report = daemon.run(printer)
            vehicle_cpu_s = (thread_cpu_s(vehicle_thread) if vehicle_thread is not None else 0.0) - vehicle_cpu0
            collisions = vehicle.state().collisions if vehicle is not None else None
            peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            rss_now_mb = resident_memory_mb()
        # The start pose's and the kernel compiler's processes (the largest of them; the picture's comes later).
        children_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        memory_mb = {"peak_rss_mb": peak_rss_mb, "rss_at_end_mb": rss_now_mb, "children_peak_rss_mb": children_mb}
        summary = run_summary(
            options,
            profile,
            model_notes,
            backends,
            raster,
            start,
            noise_seed,
            report,
            collisions,
            vehicle_cpu_s,
            memory_mb,
            daemon,
        )
        write_summary(out, summary, daemon, raster)
        print_summary(summary)
        return summary
    finally:
        logging.getLogger().removeHandler(file_log)
        file_log.close()


def _compile_kernels(raster: Any, camera: Any = None) -> None:
    """:func:`~edge_explorer.runtime.kernels.warm_kernels` in a forked child process: on a fresh install numba
    compiles the flight's kernels there (LLVM's code and working memory, ~100 MB, and ~2 s) into its on-disk
    cache, so the flight's process only loads them — as on a drone whose install step compiled them. Forked before
    the flight's heavier imports (pymavlink, LiteRT, the planners), so the child holds little else."""
    import multiprocessing

    from edge_explorer.runtime.kernels import warm_kernels

    child = multiprocessing.get_context("fork").Process(
        target=warm_kernels, args=(raster, camera), name="compile-kernels"
    )
    child.start()
    child.join()
    if child.exitcode != 0:
        raise RuntimeError(f"compiling the flight's numba kernels failed (exit code {child.exitcode})")


def _depth_source(
    spec: str, raster: Any, vehicle: Any, rate_hz: float, noise_seed: int, simulation: Simulation | None
) -> Any:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.runtime.depth_sources import RealSenseDepthSource, ReplayDepthSource

    if spec == "sim":
        if simulation is None:
            raise EdgeExplorerError("--source sim renders from the simulated vehicle, which this flight does not fly")
        return simulation.depth_source(raster, vehicle, rate_hz, noise_seed)
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
