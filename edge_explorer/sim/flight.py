"""The simulated drone that ``edge-explorer run`` flies without ``--connect``: the simulated PX4/ArduPilot vehicle
over real MAVLink on loopback UDP, the simulated depth camera, and the exploration benchmark's start pose, handed to
:func:`edge_explorer.runtime.flight.fly` as one :class:`SimulatedFlight` (its
:class:`~edge_explorer.runtime.flight.Simulation`). The command line builds it only for a simulated flight, so a
flight with a real autopilot never imports the simulator.

Every import of the simulator here is inside a function: a flight loads its numba kernels and hands back LLVM's
pages before its heavier imports (pymavlink, the renderer; :mod:`edge_explorer.runtime.kernels`).
"""

from __future__ import annotations

from typing import Any


class SimulatedFlight:
    """The simulated world of one ``edge-explorer run`` flight (see the module docstring)."""

    def camera(self, raster: Any) -> Any:
        """The simulated depth camera of ``raster`` (:class:`~edge_explorer.sim.camera.DepthCamera`)."""
        from edge_explorer.sim.camera import DepthCamera

        return DepthCamera(raster)

    @property
    def vehicle_thread(self) -> str:
        from edge_explorer.sim.vehicle import THREAD_NAME

        return THREAD_NAME

    def start_pose(self, raster: Any, seed: int) -> tuple[float, float, float]:
        return _start_pose(raster, seed)

    def vehicle(self, raster: Any, start: tuple[float, float, float], noise_seed: int, flavour: str) -> Any:
        return _simulated_vehicle(raster, start, noise_seed, flavour)

    def depth_source(self, raster: Any, vehicle: Any, rate_hz: float, noise_seed: int) -> Any:
        from edge_explorer.sim.camera import DepthCamera
        from edge_explorer.sim.depth_source import SimulatedDepthSource
        from edge_explorer.vehicle.camera import CameraPose

        camera = DepthCamera(raster)
        truth = vehicle.true_pose()
        camera.render(CameraPose(truth.x_m, truth.y_m, 1.7, truth.yaw_rad))  # load the renderer before the flight
        return SimulatedDepthSource(camera, vehicle, rate_hz=rate_hz, seed=noise_seed)


def _start_pose(raster: Any, seed: int) -> tuple[float, float, float]:
    """The exploration benchmark's start pose on the building ``raster`` (the flight's, already loaded:
    :func:`edge_explorer.sim.starts.start_pose`), drawn in a new interpreter. The draw builds the training simulator
    (~50 MB) and resets it, which compiles a dozen numba kernels (LLVM's code and working memory: ~120 MB on a fresh
    install) the flight never runs; none of that stays in the flight's process (tests/runtime/test_kernels.py checks
    the pose is the benchmark's). Until session 43 the child ran with numba's JIT off to save the compile: the
    kernels then ran interpreted, ~0.4 s on building A but more than 10 minutes on a 270 m KTH floor."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=spawn) as pool:
        return pool.submit(_draw_start_pose, raster, seed).result()


def _draw_start_pose(raster: Any, seed: int) -> tuple[float, float, float]:
    """The start pose's child's work. The flight's kernels run first (:func:`~edge_explorer.runtime.kernels.
    warm_kernels`, then LLVM's pages are released), so that on a fresh install this one call fills numba's cache for
    the whole flight and the flight's process only loads (unless numba's JIT is off). The child gets the flight's
    raster, not the plan's name: loading a whole floor again (its flight space) costs as long as the parent's load."""
    import numba

    if not numba.config.DISABLE_JIT:
        from edge_explorer.runtime.kernels import release_llvm_pages, warm_kernels

        warm_kernels(raster, SimulatedFlight().camera)
        release_llvm_pages()

    from edge_explorer.sim.starts import start_pose

    x_m, y_m, yaw_rad = start_pose(raster, seed)
    return float(x_m), float(y_m), float(yaw_rad)


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
