"""Depth sources: the simulated camera on the simulated vehicle, recording + replay, and the RealSense adapter."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from edge_explorer.runtime.depth_sources import (
    DepthFrame,
    DepthSourceError,
    RealSenseDepthSource,
    Recorder,
    ReplayDepthSource,
)
from edge_explorer.runtime.mavlink_link import Pose
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.sim.depth_source import SimulatedDepthSource
from edge_explorer.sim.vehicle import SimulatedVehicle, VehicleConfig
from edge_explorer.vehicle.camera import CameraConfig, CameraPose, DepthIntrinsics
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


@pytest.fixture(scope="module")
def camera() -> DepthCamera:
    camera = DepthCamera(rasterize(two_room_plan(), 0.05), CameraConfig())
    camera.render(CameraPose(1.0, 1.5, 1.7, 0.0))  # compile (or load) the renderer before timing anything
    return camera


def test_simulated_source_renders_the_true_pose_at_its_rate(camera: DepthCamera) -> None:
    config = VehicleConfig(start_xyz_m=(1.0, 1.5, 1.7), start_yaw_rad=np.pi)  # hovering, facing the west wall
    with SimulatedVehicle(config, camera.raster) as vehicle:
        source = SimulatedDepthSource(camera, vehicle, rate_hz=15.0, seed=None)
        frames = [source.next_frame() for _ in range(6)]
    expected = camera.render(CameraPose(1.0, 1.5, 1.7, np.pi))
    for frame in frames:
        assert frame.depth_m.shape == (120, 212) and frame.depth_m.dtype == np.float32
        np.testing.assert_array_equal(frame.depth_m, expected)
        assert frame.intrinsics == camera.config.intrinsics and frame.pose is None
    spacing = np.diff([f.stamp_s for f in frames])
    # frames keep the camera's 15 Hz schedule: single stamps jitter with the host's load, their mean does not
    assert np.all(spacing > 0) and np.mean(spacing) == pytest.approx(1 / 15, abs=0.006)
    assert not source.finished


def test_simulated_source_skips_frames_a_slow_caller_missed(camera: DepthCamera) -> None:
    with SimulatedVehicle(VehicleConfig(start_xyz_m=(1.0, 1.5, 1.7)), camera.raster) as vehicle:
        source = SimulatedDepthSource(camera, vehicle, rate_hz=20.0)
        source.next_frame()
        time.sleep(0.26)  # ~5 frame periods
        late = source.next_frame()
        on_time = source.next_frame()
    assert 4 <= source.frames_skipped <= 6
    assert 0.0 < on_time.stamp_s - late.stamp_s <= 0.05 + 0.012  # back on the camera's 20 Hz schedule


def test_recorder_and_replay_round_trip(tmp_path: Path) -> None:
    intrinsics = DepthIntrinsics.d435(8, 6)
    rng = np.random.default_rng(1)
    frames = [DepthFrame(rng.uniform(0, 5, (6, 8)).astype(np.float32), 100.0 + 0.1 * i, intrinsics) for i in range(4)]
    poses = [Pose(f.stamp_s, 1.0 + i, 2.0, 1.7, 0.5, 0.01, -0.02) for i, f in enumerate(frames)]
    with Recorder(tmp_path / "run", intrinsics) as recorder:
        for frame, pose in zip(frames[:3], poses, strict=False):
            recorder.write(frame, pose)
        recorder.write(frames[3])  # no pose known for this one
    with open(tmp_path / "run" / "depth.f32", "ab") as f:
        f.write(b"\x00" * 10)  # a frame cut short by a crash

    replay = ReplayDepthSource(tmp_path / "run")
    assert len(replay) == 4 and replay.intrinsics == intrinsics
    for i, original in enumerate(frames):
        frame = replay.next_frame()
        np.testing.assert_array_equal(frame.depth_m, original.depth_m)
        assert frame.stamp_s == original.stamp_s
        assert frame.pose == (poses[i] if i < 3 else None)
    assert replay.finished and replay.next_frame() is None


def test_realtime_replay_keeps_the_recorded_spacing(tmp_path: Path) -> None:
    intrinsics = DepthIntrinsics.d435(4, 3)
    with Recorder(tmp_path / "run", intrinsics) as recorder:
        for i in range(3):
            recorder.write(DepthFrame(np.ones((3, 4), np.float32), 50.0 + 0.1 * i, intrinsics))
    replay = ReplayDepthSource(tmp_path / "run", realtime=True)
    start = time.monotonic()
    while replay.next_frame() is not None:
        pass
    assert time.monotonic() - start == pytest.approx(0.2, abs=0.05)


def test_replay_of_something_else_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DepthSourceError, match="not a depth recording"):
        ReplayDepthSource(tmp_path)
    (tmp_path / "meta.json").write_text('{"format": "other", "version": 1}')
    with pytest.raises(DepthSourceError, match="unsupported recording format 'other'"):
        ReplayDepthSource(tmp_path)


def test_realsense_without_the_driver_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # makes the import fail
    with pytest.raises(DepthSourceError, match=r"pip install 'edge-explorer\[realsense\]'"):
        RealSenseDepthSource()


def test_realsense_frames_are_decimated_scaled_and_stamped(monkeypatch: pytest.MonkeyPatch) -> None:
    rs = fake_pyrealsense2(frame_wall_time_s=time.time() - 0.030)
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    source = RealSenseDepthSource()
    frame = source.next_frame()
    assert rs.magnitude == 4 and rs.global_time_on
    assert frame.depth_m.dtype == np.float32 and frame.depth_m.shape == (120, 212)
    assert frame.depth_m[0, 0] == pytest.approx(1.5)  # 1500 units of 1 mm
    assert frame.intrinsics == DepthIntrinsics(212, 120, 105.0, 104.0, 106.0, 60.0)
    assert time.monotonic() - frame.stamp_s == pytest.approx(0.030, abs=0.01)  # wall clock → monotonic
    source.close()
    assert rs.stopped


def fake_pyrealsense2(frame_wall_time_s: float) -> SimpleNamespace:
    """The slice of pyrealsense2 the adapter uses: a camera whose frames decimate 848×480 → 212×120."""
    rs = SimpleNamespace(magnitude=None, global_time_on=False, stopped=False)
    rs.stream = SimpleNamespace(depth="depth")
    rs.format = SimpleNamespace(z16="z16")
    rs.option = SimpleNamespace(global_time_enabled="global_time", filter_magnitude="magnitude")
    rs.timestamp_domain = SimpleNamespace(global_time="global", system_time="system", hardware_clock="hw")
    intrinsics = SimpleNamespace(width=212, height=120, fx=105.0, fy=104.0, ppx=106.0, ppy=60.0)
    decimated = SimpleNamespace(
        get_profile=lambda: SimpleNamespace(
            as_video_stream_profile=lambda: SimpleNamespace(get_intrinsics=lambda: intrinsics)
        ),
        get_data=lambda: np.full((120, 212), 1500, np.uint16),
        get_frame_timestamp_domain=lambda: rs.timestamp_domain.global_time,
        get_timestamp=lambda: frame_wall_time_s * 1000.0,
    )
    native = SimpleNamespace(as_depth_frame=lambda: decimated)
    sensor = SimpleNamespace(
        supports=lambda option: option == rs.option.global_time_enabled,
        set_option=lambda option, value: setattr(rs, "global_time_on", bool(value)),
        get_depth_scale=lambda: 0.001,
    )
    profile = SimpleNamespace(get_device=lambda: SimpleNamespace(first_depth_sensor=lambda: sensor))
    rs.config = lambda: SimpleNamespace(enable_stream=lambda *args: None, enable_device=lambda serial: None)
    rs.pipeline = lambda: SimpleNamespace(
        start=lambda config: profile,
        try_wait_for_frames=lambda timeout_ms: (True, SimpleNamespace(get_depth_frame=lambda: native)),
        stop=lambda: setattr(rs, "stopped", True),
    )
    rs.decimation_filter = lambda: SimpleNamespace(
        set_option=lambda option, value: setattr(rs, "magnitude", value),
        process=lambda frame: frame,
    )
    return rs
