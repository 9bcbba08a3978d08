"""Odometry on this host's clock: :class:`Pose` (map frame, FLU attitude), the remote-to-host clock mapping
(:class:`_ClockSync`: the autopilot's ``time_boot_ms`` onto ``time.monotonic()`` by a minimum-latency offset
estimate, so samples keep the autopilot's own spacing instead of the jitter of their arrival) and the timestamped
pose buffer that :meth:`~edge_explorer.runtime.mavlink_link.MavlinkLink.pose_at` interpolates at a depth frame's
timestamp (:class:`_PoseBuffer`)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from edge_explorer.runtime.mavlink_link.frames import (
    _wrap_rad,
)


@dataclass(frozen=True)
class Pose:
    """Vehicle pose in the ``map`` frame at ``stamp_s`` (host ``time.monotonic()`` seconds); FLU attitude.

    The attitude fields match :class:`edge_explorer.vehicle.camera.CameraPose` (positive pitch = nose down).
    """

    stamp_s: float
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    vz_mps: float = 0.0


class _ClockSync:
    """Maps a remote clock (e.g. the autopilot's ``time_boot_ms``) onto this host's monotonic clock.

    The offset is the smallest ``arrival − remote`` seen: the sample with the least transport delay. It may creep
    up by ``drift_s_per_s`` to follow clock drift, and starts over when the remote clock jumps back (a reboot) or
    the delay it implies exceeds ``reset_after_s``.
    """

    def __init__(self, drift_s_per_s: float = 1e-4, reset_after_s: float = 1.0) -> None:
        self._offset_s: float | None = None
        self._last_remote_s = 0.0
        self._last_arrival_s = 0.0
        self._drift = drift_s_per_s
        self._reset_after_s = reset_after_s

    def to_host(self, remote_s: float, arrival_s: float) -> float:
        sample = arrival_s - remote_s
        jumped_back = remote_s < self._last_remote_s - self._reset_after_s
        if self._offset_s is None or jumped_back or sample - self._offset_s > self._reset_after_s:
            self._offset_s = sample
        else:
            allowed = self._offset_s + self._drift * (arrival_s - self._last_arrival_s)
            self._offset_s = min(sample, allowed)
        self._last_remote_s = remote_s
        self._last_arrival_s = arrival_s
        return remote_s + self._offset_s


class _PoseBuffer:
    """Timestamped position and attitude samples (they arrive in separate messages), interpolated on demand."""

    def __init__(self, horizon_s: float, max_extrapolation_s: float) -> None:
        self._horizon_s = horizon_s
        self._max_extrapolation_s = max_extrapolation_s
        # (stamp, x, y, z, vx, vy, vz) and (stamp, roll, pitch, yaw, yaw_rate), map frame, sorted by stamp.
        self._positions: list[tuple[float, ...]] = []
        self._attitudes: list[tuple[float, ...]] = []
        self.out_of_order = 0

    def add_position(self, stamp_s: float, xyz: tuple[float, float, float], vxyz: tuple[float, float, float]) -> None:
        self._append(self._positions, (stamp_s, *xyz, *vxyz))

    def add_attitude(self, stamp_s: float, roll: float, pitch: float, yaw: float, yaw_rate: float) -> None:
        self._append(self._attitudes, (stamp_s, roll, pitch, yaw, yaw_rate))

    def _append(self, samples: list[tuple[float, ...]], sample: tuple[float, ...]) -> None:
        if samples and sample[0] <= samples[-1][0]:
            self.out_of_order += 1
            return
        samples.append(sample)
        cutoff = sample[0] - self._horizon_s
        if samples[0][0] < cutoff:
            del samples[: bisect.bisect_left(samples, (cutoff,))]

    def newest_stamp_s(self) -> float | None:
        if not self._positions or not self._attitudes:
            return None
        return min(self._positions[-1][0], self._attitudes[-1][0])

    def pose_at(self, t_s: float) -> Pose | None:
        pos = _interpolate(self._positions, t_s, self._max_extrapolation_s, velocity_cols=(4, 5, 6))
        att = _interpolate(self._attitudes, t_s, self._max_extrapolation_s, velocity_cols=(None, None, 4), angle=3)
        if pos is None or att is None:
            return None
        return Pose(t_s, pos[1], pos[2], pos[3], att[3], att[2], att[1], pos[4], pos[5], pos[6])


def _interpolate(
    samples: list[tuple[float, ...]],
    t_s: float,
    max_extrapolation_s: float,
    velocity_cols: tuple[int | None, ...],
    angle: int | None = None,
) -> tuple[float, ...] | None:
    """Linear interpolation of the sample tuples at ``t_s`` (column ``angle`` along the shortest arc).

    Past the newest sample, columns 1-3 are extrapolated with the rates in ``velocity_cols`` for at most
    ``max_extrapolation_s``; up to that long before the oldest sample, the oldest is held (position and attitude
    arrive at slightly different times); earlier than that there is nothing to say.
    """
    if not samples or t_s < samples[0][0] - max_extrapolation_s:
        return None
    if t_s <= samples[0][0]:
        return samples[0]
    newest = samples[-1]
    if t_s >= newest[0]:
        dt = t_s - newest[0]
        if dt > max_extrapolation_s:
            return None
        out = list(newest)
        for col, rate_col in zip((1, 2, 3), velocity_cols, strict=True):
            if rate_col is not None:
                out[col] += newest[rate_col] * dt
        if angle is not None:
            out[angle] = _wrap_rad(out[angle])
        return tuple(out)
    i = bisect.bisect_right(samples, (t_s, math.inf))
    a, b = samples[i - 1], samples[i]
    w = (t_s - a[0]) / (b[0] - a[0])
    out = [av + w * (bv - av) for av, bv in zip(a, b, strict=True)]
    if angle is not None:
        out[angle] = _wrap_rad(a[angle] + w * _wrap_rad(b[angle] - a[angle]))
    return tuple(out)
