"""Depth sources for the daemon, all behind one small interface (:class:`DepthSource`).

* :class:`~edge_explorer.sim.depth_source.SimulatedDepthSource` (in the simulator) — renders the simulated camera
  from the simulated vehicle's TRUE pose at a fixed rate (default 15 Hz); the daemon fuses each frame with the
  odometry pose the link reports at the frame's stamp, so odometry noise and latency act on the map exactly as they
  would in flight.
* :class:`ReplayDepthSource` — plays back a run written by :class:`Recorder` (frames, stamps and the pose used).
* :class:`RealSenseDepthSource` — an Intel RealSense D4xx through pyrealsense2 (the ``realsense`` extra), decimated
  4× to 212×120 like the simulated camera.

Every frame is z-depth in metres, float32, 0 = no return, stamped on this host's ``time.monotonic()`` clock — the
clock of :meth:`edge_explorer.runtime.mavlink_link.MavlinkLink.pose_at`.

Recording layout (a folder, append-only, so a crash loses at most the frame being written)::

    meta.json    {"format": "edge-explorer-depth", "version": 1, "intrinsics": {...DepthIntrinsics fields}}
    depth.f32    the frames, each height×width little-endian float32, back to back
    frames.csv   index,stamp_s,x_m,y_m,z_m,yaw_rad,pitch_rad,roll_rad   (pose fields empty when none was given)
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.runtime.mavlink_link import Pose
from edge_explorer.vehicle.camera import DepthIntrinsics

RECORDING_FORMAT = "edge-explorer-depth"
RECORDING_VERSION = 1
_POSE_FIELDS = ("x_m", "y_m", "z_m", "yaw_rad", "pitch_rad", "roll_rad")


class DepthSourceError(EdgeExplorerError):
    """A depth source cannot be opened or read (missing driver, bad recording, no camera)."""


@dataclass(frozen=True)
class DepthFrame:
    """One depth image: float32 metres (H×W, 0 = no return), its host-monotonic stamp and the camera model.

    ``pose`` is the pose stored with the frame by a recording (replay only); live sources leave it None and the
    daemon asks the MAVLink link for the pose at ``stamp_s``.
    """

    depth_m: np.ndarray
    stamp_s: float
    intrinsics: DepthIntrinsics
    pose: Pose | None = None


class DepthSource(Protocol):
    """What the daemon reads frames from."""

    @property
    def intrinsics(self) -> DepthIntrinsics: ...

    @property
    def finished(self) -> bool:
        """True when no frame will ever come again (the end of a replay)."""
        ...

    def next_frame(self, timeout_s: float = 1.0) -> DepthFrame | None:
        """The next frame, waiting at most ``timeout_s``; None when none came in time (or the source is finished)."""
        ...

    def close(self) -> None: ...


class Recorder:
    """Writes depth frames (and the pose they were fused with) to a recording folder; see the module doc."""

    def __init__(self, folder: Path, intrinsics: DepthIntrinsics) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self.folder = folder
        self._intrinsics = intrinsics
        meta = {"format": RECORDING_FORMAT, "version": RECORDING_VERSION, "intrinsics": asdict(intrinsics)}
        (folder / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
        self._depth = open(folder / "depth.f32", "wb")  # noqa: SIM115 - closed by close()
        self._index_file = open(folder / "frames.csv", "w", newline="")  # noqa: SIM115 - closed by close()
        self._index = csv.writer(self._index_file)
        self._index.writerow(("index", "stamp_s", *_POSE_FIELDS))
        self.frames_written = 0

    def write(self, frame: DepthFrame, pose: Pose | None = None) -> None:
        """Append ``frame``; ``pose`` (default: the frame's own) is stored for replay."""
        if frame.depth_m.shape != self._intrinsics.shape:
            raise ValueError(f"frame shape {frame.depth_m.shape} differs from the recording's {self._intrinsics.shape}")
        pose = pose if pose is not None else frame.pose
        self._depth.write(np.ascontiguousarray(frame.depth_m, dtype="<f4").tobytes())
        fields = ["" if pose is None else repr(float(getattr(pose, name))) for name in _POSE_FIELDS]
        self._index.writerow((self.frames_written, repr(float(frame.stamp_s)), *fields))
        self.frames_written += 1

    def close(self) -> None:
        self._depth.close()
        self._index_file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ReplayDepthSource:
    """Frames of a :class:`Recorder` folder in order, with their original stamps and stored poses.

    ``realtime=True`` waits between frames as long as the recording did; otherwise frames come as fast as asked.
    A frame cut short by a crash at the end of ``depth.f32`` is ignored.
    """

    def __init__(self, folder: Path, realtime: bool = False) -> None:
        meta_path = folder / "meta.json"
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DepthSourceError(f"{folder}: not a depth recording ({meta_path.name}: {exc})") from exc
        if meta.get("format") != RECORDING_FORMAT or meta.get("version") != RECORDING_VERSION:
            raise DepthSourceError(
                f"{folder}: unsupported recording format {meta.get('format')!r} v{meta.get('version')!r} "
                f"(expected {RECORDING_FORMAT!r} v{RECORDING_VERSION})"
            )
        self._intrinsics = DepthIntrinsics(**meta["intrinsics"])
        rows, cols = self._intrinsics.shape
        depth_path = folder / "depth.f32"
        frame_bytes = rows * cols * 4
        complete = depth_path.stat().st_size // frame_bytes if depth_path.exists() else 0
        # Memory-mapped: a long recording is not read into memory at once.
        self._frames = (
            np.memmap(depth_path, dtype="<f4", mode="r", shape=(complete, rows, cols))
            if complete
            else np.zeros((0, rows, cols), np.float32)
        )
        with open(folder / "frames.csv", newline="") as f:
            self._rows = list(csv.DictReader(f))[:complete]
        self._realtime = realtime
        self._position = 0
        self._started: tuple[float, float] | None = None  # (wall start, first stamp) for realtime pacing

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def intrinsics(self) -> DepthIntrinsics:
        return self._intrinsics

    @property
    def finished(self) -> bool:
        return self._position >= len(self._rows)

    def next_frame(self, timeout_s: float = 1.0) -> DepthFrame | None:
        if self.finished:
            return None
        row = self._rows[self._position]
        stamp_s = float(row["stamp_s"])
        if self._realtime:
            if self._started is None:
                self._started = (time.monotonic(), stamp_s)
            wait_s = self._started[0] + (stamp_s - self._started[1]) - time.monotonic()
            if wait_s > timeout_s:
                time.sleep(max(timeout_s, 0.0))
                return None
            time.sleep(max(wait_s, 0.0))
        pose = None
        if row["x_m"] != "":
            values = {name: float(row[name]) for name in _POSE_FIELDS}
            pose = Pose(stamp_s, **values)
        frame = DepthFrame(np.array(self._frames[self._position]), stamp_s, self._intrinsics, pose)
        self._position += 1
        return frame

    def close(self) -> None:
        self._frames = np.zeros((0, *self._intrinsics.shape), np.float32)  # releases the memory map
        self._position = len(self._rows)


class RealSenseDepthSource:
    """An Intel RealSense depth camera (D435/D455…) through pyrealsense2, decimated to the daemon's resolution.

    Streams ``width_px``×``height_px`` z16 at ``fps`` and applies the RealSense decimation filter (``decimation``,
    default 4: 848×480 → 212×120). Stamps: with the camera's global time (host-synchronised), frame timestamps are
    converted from the host's wall clock to ``time.monotonic()``; otherwise the arrival time is used.
    """

    def __init__(
        self,
        width_px: int = 848,
        height_px: int = 480,
        fps: int = 15,
        decimation: int = 4,
        serial_number: str | None = None,
    ) -> None:
        try:
            import pyrealsense2 as rs
        except ImportError as exc:
            raise DepthSourceError(
                "the RealSense source needs pyrealsense2: pip install 'edge-explorer[realsense]'"
            ) from exc
        self._rs = rs
        config = rs.config()
        if serial_number:
            config.enable_device(serial_number)
        config.enable_stream(rs.stream.depth, width_px, height_px, rs.format.z16, fps)
        self._pipeline = rs.pipeline()
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            raise DepthSourceError(
                f"no RealSense camera could stream depth {width_px}×{height_px} @ {fps} Hz: {exc}"
            ) from exc
        sensor = profile.get_device().first_depth_sensor()
        if sensor.supports(rs.option.global_time_enabled):
            sensor.set_option(rs.option.global_time_enabled, 1)
        self._depth_scale_m = float(sensor.get_depth_scale())
        self._decimate = rs.decimation_filter()
        self._decimate.set_option(rs.option.filter_magnitude, decimation)
        self._intrinsics: DepthIntrinsics | None = None

    @property
    def intrinsics(self) -> DepthIntrinsics:
        if self._intrinsics is None:
            raise DepthSourceError("RealSense intrinsics are known after the first frame")
        return self._intrinsics

    @property
    def finished(self) -> bool:
        return False

    def next_frame(self, timeout_s: float = 1.0) -> DepthFrame | None:
        rs = self._rs
        ok, frames = self._pipeline.try_wait_for_frames(max(1, int(timeout_s * 1000)))
        if not ok:
            return None
        arrival_s = time.monotonic()
        depth = frames.get_depth_frame()
        if not depth:
            return None
        decimated = self._decimate.process(depth).as_depth_frame()
        if self._intrinsics is None:
            k = decimated.get_profile().as_video_stream_profile().get_intrinsics()
            self._intrinsics = DepthIntrinsics(k.width, k.height, k.fx, k.fy, k.ppx, k.ppy)
        depth_m = np.asanyarray(decimated.get_data()).astype(np.float32) * np.float32(self._depth_scale_m)
        stamp_s = arrival_s
        domain = decimated.get_frame_timestamp_domain()
        if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
            wall_to_monotonic_s = time.time() - time.monotonic()
            stamp_s = min(decimated.get_timestamp() / 1000.0 - wall_to_monotonic_s, arrival_s)
        return DepthFrame(depth_m, stamp_s, self._intrinsics)

    def close(self) -> None:
        self._pipeline.stop()
