"""The setpoint stream: :class:`SetpointFeeder`, a thread that samples the active minimum-jerk segment at the
setpoint rate and hands it to the MAVLink link, which streams it (with its heartbeat) to the autopilot."""

from __future__ import annotations

import logging
import threading
import time

from edge_explorer.plan.trajectory import MinJerkSegment, TrajectoryState
from edge_explorer.runtime.daemon.report import StageTimings
from edge_explorer.runtime.mavlink_link import MavlinkLink

log = logging.getLogger(__name__)


class SetpointFeeder:
    """A thread that samples the active minimum-jerk segment at ``rate_hz`` and hands it to the link.

    :meth:`follow` queues a segment starting at a given time (the previous one keeps running until then);
    :meth:`clear` stops feeding — afterwards the link streams whatever target it was given last (a hold).
    """

    def __init__(self, link: MavlinkLink, rate_hz: float, timings: StageTimings) -> None:
        self._link = link
        self._period_s = 1.0 / rate_hz
        self._timings = timings
        self._lock = threading.Lock()
        self._segments: list[tuple[float, MinJerkSegment]] = []  # (start_s, segment), by start time
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoint-feeder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self.clear()
        self._stop.set()
        self._thread.join(timeout=1.0)

    def follow(self, segment: MinJerkSegment, start_s: float) -> None:
        with self._lock:
            self._segments = [s for s in self._segments if s[0] < start_s][-1:] + [(start_s, segment)]

    def clear(self) -> None:
        with self._lock:
            self._segments = []

    @property
    def end_s(self) -> float | None:
        """When the last queued segment ends; None when nothing is being fed."""
        with self._lock:
            return None if not self._segments else self._segments[-1][0] + self._segments[-1][1].duration_s

    def state_at(self, t_s: float) -> TrajectoryState | None:
        """The reference at ``t_s`` (held at a segment's end after it); None when nothing is being fed."""
        with self._lock:
            return self._state_at(t_s)

    def _state_at(self, t_s: float) -> TrajectoryState | None:
        active = [s for s in self._segments if s[0] <= t_s] or self._segments[:1]
        if not active:
            return None
        start_s, segment = active[-1]
        return segment.state_at(t_s - start_s)

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self._period_s
            with self._lock:  # held while setting, so that after clear() no stale target is set
                state = self._state_at(time.monotonic())
                if state is None:
                    continue
                start = time.perf_counter()
                try:
                    x, y, z, yaw = (float(v) for v in state.position)
                    self._link.set_target(x, y, z, yaw)
                except Exception:  # noqa: BLE001 - the stream must outlive any single bad sample
                    log.exception("setpoint feeder error")
                self._timings.add("mavlink_io", time.perf_counter() - start)
            if next_s < time.monotonic() - self._period_s:  # fell behind: no burst
                next_s = time.monotonic() + self._period_s
