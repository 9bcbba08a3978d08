"""Measure the daemon's real loop: the simulated vehicle and depth camera over MAVLink on loopback UDP.

The profiler does not re-implement the loop: it builds the same :class:`~edge_explorer.runtime.daemon.Daemon` as
``edge-explorer run`` (shipped models loaded through the backend chain, the simulated PX4 vehicle, the simulated
depth camera) and reads the daemon's own :class:`~edge_explorer.runtime.daemon.StageTimings`. The first
``warmup_decisions`` decisions (JIT compilation, caches, the backends' first runs) are cut off every stage's
samples; the run stops after ``decisions`` more.

With ``record_dir`` the flight is also recorded (the daemon's :class:`~edge_explorer.runtime.depth_sources.Recorder`:
every fused frame with the pose it was fused with) together with ``loop_timings.json`` — every fuse, project and
predictor call's duration in the loop, where the measured window starts, after how many fused frames each decision
came, and the thread CPU time and preemptions of each fuse call — so an independent measurement can replay exactly
the calls the loop timed, on the same inputs (``scripts/independent_check.py``).

CPU: like ``edge-explorer run``, the daemon's share is the process's CPU time minus the simulated world's (the
vehicle's physics thread and the depth renderer, which is the camera's work on a real drone), over the measured
window's wall time. Peak RSS is the process's high-water mark after the loop (it includes the simulated world's
plan raster and renderer, a few MB).
"""

from __future__ import annotations

import json
import logging
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.backends.card import CARD_FILE, load_card
from edge_explorer.runtime.daemon import (
    STAGES,
    CoverageTruth,
    Daemon,
    DaemonConfig,
    ModelSetupError,
    Progress,
    choose_models,
)
from edge_explorer.runtime.depth_sources import DepthFrame, DepthSource, Recorder
from edge_explorer.runtime.flight import thread_cpu_s
from edge_explorer.sim.vehicle import THREAD_NAME as SIM_VEHICLE_THREAD
from edge_explorer.vehicle.camera import DepthIntrinsics

log = logging.getLogger(__name__)

RECORDED_TIMINGS = "loop_timings.json"  # written beside a recording (LoopOptions.record_dir)
REPLAYED_STAGES: tuple[str, ...] = ("fuse", "project", "predictor", "policy")


@dataclass(frozen=True)
class LoopOptions:
    """One measured flight. ``plan``: a building reference (``A``–``D`` or a plan file, see world/catalog.py).

    ``replay_dir``: a recording (``record_dir`` of an earlier flight) supplies the frames and the poses they are
    fused with, paced as recorded, while the simulated vehicle still flies the daemon's setpoints: the same fuse
    calls as the recorded flight without the renderer's work in the process.
    """

    models_dir: Path
    backend_order: tuple[str, ...]
    model_orders: dict[str, tuple[str, ...]] = field(default_factory=dict)  # per-model overrides of backend_order
    record_dir: Path | None = None
    replay_dir: Path | None = None  # frames (and their poses) from this recording instead of the simulated camera
    plan: str = "A"
    decisions: int = 60
    warmup_decisions: int = 5
    depth_hz: float = 15.0
    setpoint_hz: float = 20.0
    seed: int = 0
    start_height_m: float = 0.0  # above 0 the vehicle starts airborne (a shorter climb: tests)
    daemon: DaemonConfig = DaemonConfig(time_limit_s=3600.0, return_home=False, progress_every_s=0.05)

    def __post_init__(self) -> None:
        if self.decisions < 1 or self.warmup_decisions < 0:
            raise ValueError("decisions must be ≥ 1 and warmup_decisions ≥ 0")
        if self.record_dir is not None and self.replay_dir is not None and self.record_dir == self.replay_dir:
            raise ValueError("record_dir must differ from replay_dir: recording would overwrite the frames it plays")


@dataclass(frozen=True)
class LoopMeasurement:
    """What one measured flight gives the report: raw per-stage samples after warm-up (milliseconds) and more."""

    samples_ms: dict[str, np.ndarray]  # stage → samples, only stages that ran
    decisions: int
    frames_fused: int
    wall_s: float  # the measured window (after warm-up)
    daemon_cpu_percent: float  # of one core, over the measured window
    process_cpu_percent: float
    peak_rss_mb: float
    planner: str
    engines: dict[str, tuple[str, str, str]]  # policy / predictor → (backend, precision, artifact file), if loaded
    model_notes: tuple[str, ...]  # why each model is (not) used, from the daemon's model choice
    ending: str
    plan: str
    recording: str | None = None  # the record_dir, when the flight was recorded


class _MeteredSource:
    """A depth source that adds up the CPU time its frames cost (the renderer's, in simulation)."""

    def __init__(self, inner: DepthSource) -> None:
        self.inner = inner
        self.cpu_s = 0.0

    @property
    def intrinsics(self) -> DepthIntrinsics:
        return self.inner.intrinsics

    @property
    def finished(self) -> bool:
        return self.inner.finished

    def next_frame(self, timeout_s: float = 1.0) -> DepthFrame | None:
        cpu0 = time.thread_time()
        try:
            return self.inner.next_frame(timeout_s)
        finally:
            self.cpu_s += time.thread_time() - cpu0

    def close(self) -> None:
        self.inner.close()


class _Window:
    """The measured window: marks the sample counts, CPU and wall clock when warm-up ends, and stops the daemon."""

    def __init__(
        self, daemon: Daemon, source: _MeteredSource, options: LoopOptions, on_decision: Callable[[int], None]
    ) -> None:
        self.daemon = daemon
        self.source = source
        self.options = options
        self.on_decision = on_decision
        self.start_counts: dict[str, int] | None = None
        self.start: tuple[float, float, float, float] | None = None  # wall, process cpu, vehicle cpu, source cpu
        self.end: tuple[float, float, float, float] | None = None
        self.seen = 0
        self.decision_frames: list[int] = []  # frames fused when each decision was seen (for the recording)
        self.fuse_cpu_ms: list[float] = []  # thread CPU time of each fuse call from fuse_cpu_from on (recording)
        self.fuse_preempted: list[int] = []  # involuntary context switches of the thread during each of them
        self.fuse_cpu_from: int | None = None

    def _meter_fuse_cpu(self) -> None:
        """Also time the thread CPU of every fuse call of the daemon's maps, once they exist, and count the times
        the scheduler took the core away during it: beside the loop's wall time they tell time spent waiting for a
        core from time spent computing."""
        maps = self.daemon.maps
        if maps is None:
            return
        inner = maps.fuse

        def metered(*args: Any, **kwargs: Any) -> Any:
            switches0, cpu0 = resource.getrusage(resource.RUSAGE_THREAD).ru_nivcsw, time.thread_time()
            stats = inner(*args, **kwargs)
            self.fuse_cpu_ms.append(1e3 * (time.thread_time() - cpu0))
            self.fuse_preempted.append(resource.getrusage(resource.RUSAGE_THREAD).ru_nivcsw - switches0)
            return stats

        maps.fuse = metered  # type: ignore[method-assign]
        self.fuse_cpu_from = len(self.daemon.timings.samples_ms("fuse"))

    def clock(self) -> tuple[float, float, float, float]:
        return time.monotonic(), time.process_time(), thread_cpu_s(SIM_VEHICLE_THREAD), self.source.cpu_s

    def __call__(self, progress: Progress) -> None:
        if self.fuse_cpu_from is None and self.options.record_dir is not None:
            self._meter_fuse_cpu()
        if progress.decisions > self.seen:
            self.on_decision(progress.decisions - self.seen)
            frames = len(self.daemon.timings.samples_ms("fuse"))
            self.decision_frames.extend([frames] * (progress.decisions - self.seen))
            self.seen = progress.decisions
        warm = self.options.warmup_decisions
        if self.start_counts is None and progress.decisions >= warm:
            self.start_counts = {s: len(self.daemon.timings.samples_ms(s)) for s in STAGES}
            self.start = self.clock()
        if self.end is None and progress.decisions >= warm + self.options.decisions:
            self.end = self.clock()
            self.daemon.request_stop("measured decisions reached")


def measure_loop(options: LoopOptions, on_decision: Callable[[int], None] = lambda n: None) -> LoopMeasurement:
    """Fly the simulated drone until ``warmup_decisions + decisions`` decisions, return the measured window.

    Raises :class:`~edge_explorer.errors.EdgeExplorerError` (one line) for a bad plan; models that cannot be loaded
    are not an error: the loop runs without them and ``model_notes`` says why.
    """
    from contextlib import ExitStack

    from edge_explorer.runtime.depth_sources import ReplayDepthSource
    from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink
    from edge_explorer.sim.camera import DepthCamera
    from edge_explorer.sim.depth_source import SimulatedDepthSource
    from edge_explorer.sim.starts import start_pose
    from edge_explorer.sim.vehicle import OdometryNoise, SimulatedVehicle, VehicleConfig
    from edge_explorer.vehicle.camera import CameraPose
    from edge_explorer.world.catalog import load_building
    from edge_explorer.world.seeds import run_seed

    raster = load_building(options.plan)
    noise_seed = run_seed(options.seed, raster.name, 0)
    # The policy is timed whenever one ships, flight-ready or not: this loop measures latency, not exploration.
    try:
        models = choose_models(options.models_dir, "drl", options.backend_order, model_orders=options.model_orders)
    except ModelSetupError:  # no usable policy: the frontier planner flies, and the notes say why
        models = choose_models(options.models_dir, "auto", options.backend_order, model_orders=options.model_orders)
    for note in models.notes:
        log.info(note)
    config = replace(options.daemon, setpoint_rate_hz=options.setpoint_hz, decision_lead_s=1.0 / options.depth_hz)
    start = start_pose(raster, options.seed)
    vehicle_config = VehicleConfig(
        connect="udpin:127.0.0.1:0",
        start_xyz_m=(start[0], start[1], options.start_height_m),
        start_yaw_rad=start[2],
        odometry_noise=OdometryNoise(position_drift_m_per_sqrt_s=0.0, yaw_drift_rad_per_sqrt_s=0.0, seed=noise_seed),
    )
    with ExitStack() as stack:
        vehicle = stack.enter_context(SimulatedVehicle(vehicle_config, raster))
        link_config = LinkConfig(connect=f"udpout:127.0.0.1:{vehicle.address[1]}", setpoint_rate_hz=options.setpoint_hz)
        link = stack.enter_context(MavlinkLink(link_config))
        if options.replay_dir is not None:  # paced as recorded; the daemon fuses each frame with its stored pose
            inner: DepthSource = ReplayDepthSource(options.replay_dir, realtime=True)
        else:
            camera = DepthCamera(raster)
            camera.render(CameraPose(start[0], start[1], 1.7, start[2]))  # compile the renderer before the flight
            inner = SimulatedDepthSource(camera, vehicle, rate_hz=options.depth_hz, seed=noise_seed)
        source = _MeteredSource(inner)
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
            truth=CoverageTruth(raster),
            recorder=recorder,
        )
        window = _Window(daemon, source, options, on_decision)
        report = daemon.run(window)
        end = window.end or window.clock()
        peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if window.start is None or window.start_counts is None:
        raise RuntimeError(f"the flight ended ({report.ending}) before warm-up was over: no measurement")
    wall_s = end[0] - window.start[0]
    process_cpu_s = end[1] - window.start[1]
    world_cpu_s = (end[2] - window.start[2]) + (end[3] - window.start[3])
    if options.record_dir is not None:
        _write_timings(options.record_dir / RECORDED_TIMINGS, daemon, window, raster.name, config)
    samples = {}
    for stage in STAGES:
        ms = daemon.timings.samples_ms(stage)[window.start_counts[stage] :]
        if len(ms):
            samples[stage] = ms
    return LoopMeasurement(
        samples_ms=samples,
        decisions=len(samples.get("decision", ())),
        frames_fused=len(samples.get("fuse", ())),
        wall_s=wall_s,
        daemon_cpu_percent=100.0 * (process_cpu_s - world_cpu_s) / wall_s,
        process_cpu_percent=100.0 * process_cpu_s / wall_s,
        peak_rss_mb=peak_rss_mb,
        planner=report.planner,
        engines=_engines(models),
        model_notes=models.notes,
        ending=report.ending,
        plan=raster.name,
        recording=None if options.record_dir is None else str(options.record_dir),
    )


def _write_timings(path: Path, daemon: Daemon, window: _Window, plan: str, config: DaemonConfig) -> None:
    """The loop's own per-call durations of the replayable stages, beside the recording (see the module doc)."""
    assert window.start_counts is not None
    doc = {
        "plan": plan,
        "band": {"min_z_m": config.band.min_z_m, "max_z_m": config.band.max_z_m, "flight_z_m": config.band.flight_z_m},
        "footprint_clear_m": config.footprint_clear_m,
        "window_start": {s: window.start_counts[s] for s in REPLAYED_STAGES},
        "decision_frames": window.decision_frames,
        "samples_ms": {s: daemon.timings.samples_ms(s).round(4).tolist() for s in REPLAYED_STAGES},
        "fuse_cpu_from": window.fuse_cpu_from,  # fuse sample index of fuse_cpu_ms[0]
        "fuse_cpu_ms": np.round(window.fuse_cpu_ms, 4).tolist(),
        "fuse_preempted": window.fuse_preempted,
    }
    path.write_text(json.dumps(doc) + "\n")


def _engines(models: Any) -> dict[str, tuple[str, str, str]]:
    """Where each loaded model runs: backend, the artifact's precision (from its card) and the artifact's name."""
    out = {}
    for name, runtime in (("policy", models.policy), ("predictor", models.predictor)):
        if runtime is not None:
            loaded = runtime.model
            card = load_card(loaded.artifact.parent / CARD_FILE)
            out[name] = (loaded.backend.name, card.artifacts[loaded.artifact.name].precision, loaded.artifact.name)
    return out
