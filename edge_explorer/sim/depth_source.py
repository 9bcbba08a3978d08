"""The simulated depth camera as a daemon depth source (:class:`~edge_explorer.runtime.depth_sources.DepthSource`):
frames rendered from the simulated vehicle's true pose at a fixed rate (default 15 Hz); the daemon fuses each frame
with the odometry pose the link reports at the frame's stamp, so odometry noise and latency act on the map exactly as
they would in flight."""

from __future__ import annotations

import time

import numpy as np

from edge_explorer.runtime.depth_sources import DepthFrame
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.sim.vehicle import SimulatedVehicle
from edge_explorer.vehicle.camera import CameraPose, DepthIntrinsics


class SimulatedDepthSource:
    """Frames rendered from the simulated vehicle's true pose at ``rate_hz``.

    ``next_frame`` sleeps until the next frame is due, then renders. A caller that falls behind gets the current
    frame, not a backlog: late frames are skipped (and counted in ``frames_skipped``), as a camera driver drops them.
    """

    def __init__(
        self, camera: DepthCamera, vehicle: SimulatedVehicle, rate_hz: float = 15.0, seed: int | None = 0
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self._camera = camera
        self._vehicle = vehicle
        self._period_s = 1.0 / rate_hz
        self._rng = None if seed is None else np.random.default_rng(seed)
        self._next_s = time.monotonic()
        self.frames_skipped = 0

    @property
    def intrinsics(self) -> DepthIntrinsics:
        return self._camera.config.intrinsics

    @property
    def finished(self) -> bool:
        return False

    def next_frame(self, timeout_s: float = 1.0) -> DepthFrame | None:
        wait_s = self._next_s - time.monotonic()
        if wait_s > timeout_s:
            time.sleep(max(timeout_s, 0.0))
            return None
        if wait_s > 0:
            time.sleep(wait_s)
        now = time.monotonic()
        missed = int((now - self._next_s) / self._period_s)
        self.frames_skipped += missed
        self._next_s += (missed + 1) * self._period_s
        truth = self._vehicle.true_pose()
        pose = CameraPose(truth.x_m, truth.y_m, truth.z_m, truth.yaw_rad, truth.pitch_rad, truth.roll_rad)
        return DepthFrame(self._camera.render(pose, self._rng), truth.stamp_s, self.intrinsics)

    def close(self) -> None:
        """Nothing to release: the camera and vehicle belong to the caller."""
