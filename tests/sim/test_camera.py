import math

import numpy as np
import pytest

from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import R_BODY_FROM_OPTICAL, CameraConfig, CameraPose, DepthIntrinsics, DepthNoise
from edge_explorer.world.plan import FloorPlan, Furniture, Rect
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

# two_room_plan: 4 m × 3 m, walls 0.1 m (inner faces x = 0.1, 3.9; y = 0.1, 2.9), divider x ∈ [1.95, 2.05] with a
# door at y ∈ [1, 2]; tall cabinet (1.8 m) on x ∈ [0.1, 0.7], y ∈ [2.4, 2.9]; low table (0.75 m) on
# x ∈ [2.8, 3.4], y ∈ [0.6, 1.2]; ceiling 3.0 m.


@pytest.fixture(scope="module")
def camera() -> DepthCamera:
    return DepthCamera(rasterize(two_room_plan(), 0.05), CameraConfig())


def centre(depth: np.ndarray) -> np.ndarray:
    """The 2×2 pixels around the optical axis (the image has even size)."""
    rows, cols = depth.shape
    return depth[rows // 2 - 1 : rows // 2 + 1, cols // 2 - 1 : cols // 2 + 1]


def test_d435_intrinsics_span_the_field_of_view() -> None:
    k = DepthIntrinsics.d435()
    assert k.shape == (120, 212)
    xn, yn = k.normalized_coords()
    # The outer pixel edges (half a pixel beyond the outer centres) lie on the 87° × 58° frustum.
    assert math.degrees(2 * math.atan(xn[-1] + 0.5 / k.fx_px)) == pytest.approx(87.0)
    assert math.degrees(2 * math.atan(yn[-1] + 0.5 / k.fy_px)) == pytest.approx(58.0)
    assert xn[0] == pytest.approx(-xn[-1])
    native = DepthIntrinsics.d435(848, 480)
    assert native.fx_px == pytest.approx(4 * k.fx_px)


def test_optical_frame_convention() -> None:
    # Optical z (forward) is body +x, optical x (right) is body −y, optical y (down) is body −z.
    np.testing.assert_array_equal(R_BODY_FROM_OPTICAL @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_array_equal(R_BODY_FROM_OPTICAL @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_array_equal(R_BODY_FROM_OPTICAL @ [0, 1, 0], [0, 0, -1])
    forward = CameraPose(0, 0, 0, yaw_rad=math.pi / 2).rotation_map_from_optical() @ [0, 0, 1]
    np.testing.assert_allclose(forward, [0, 1, 0], atol=1e-12)  # yaw is counter-clockwise from +x
    nose_down = CameraPose(0, 0, 0, 0, pitch_rad=0.3).rotation_map_from_optical() @ [0, 0, 1]
    assert nose_down[2] < 0  # positive pitch tilts the view down (FLU, REP 103)


def test_wall_at_known_distance_gives_that_z_depth(camera: DepthCamera) -> None:
    # Facing −x from x = 1.0: the inner face of the west wall is 0.9 m ahead. z-depth is the same across a
    # fronto-parallel wall, so every pixel of the middle rows that sees the wall reads 0.9.
    depth = camera.render(CameraPose(1.0, 1.5, 1.7, yaw_rad=math.pi))
    np.testing.assert_allclose(centre(depth), 0.9, atol=1e-6)
    np.testing.assert_allclose(depth[60, 80:130], 0.9, atol=1e-6)
    # Through the door (y ∈ [1, 2]) facing +x: the east wall's inner face at x = 3.9.
    depth = camera.render(CameraPose(1.0, 1.5, 1.7, yaw_rad=0.0))
    np.testing.assert_allclose(centre(depth), 2.9, atol=1e-6)


def test_floor_and_ceiling_planes(camera: DepthCamera) -> None:
    down = camera.render(CameraPose(1.0, 1.5, 1.7, 0.0, pitch_rad=math.pi / 2))
    np.testing.assert_allclose(centre(down), 1.7, atol=1e-6)
    up = camera.render(CameraPose(1.0, 1.5, 1.7, 0.0, pitch_rad=-math.pi / 2))
    np.testing.assert_allclose(centre(up), 3.0 - 1.7, atol=1e-6)


def test_low_and_tall_furniture_are_solid(camera: DepthCamera) -> None:
    # Looking straight down onto the low table top (0.75 m) from 1.7 m.
    table = camera.render(CameraPose(3.1, 0.9, 1.7, 0.0, pitch_rad=math.pi / 2))
    np.testing.assert_allclose(centre(table), 1.7 - 0.75, atol=1e-6)
    # Level view at 0.5 m height towards the table's west face (x = 2.8) from x = 2.3: 0.5 m.
    side = camera.render(CameraPose(2.3, 0.9, 0.5, 0.0))
    np.testing.assert_allclose(centre(side), 0.5, atol=1e-6)
    # At flight height the camera looks over the table to the east wall (x = 3.9).
    over = camera.render(CameraPose(2.3, 0.9, 1.7, 0.0))
    np.testing.assert_allclose(centre(over), 1.6, atol=1e-6)
    # The tall cabinet's south face (y = 2.4) from y = 1.4, facing +y at flight height.
    cabinet = camera.render(CameraPose(0.4, 1.4, 1.7, math.pi / 2))
    np.testing.assert_allclose(centre(cabinet), 1.0, atol=1e-6)


def test_top_face_hit_when_looking_down_onto_an_obstacle() -> None:
    # A 1 m high box 1 m ahead of a camera at 1.5 m pitched 45° down: the ray descends onto the box top
    # (z = 1.0) at 0.5 m horizontal distance, before the box's side face.
    walls = (Rect(0, 0, 6, 0.1), Rect(0, 3.9, 6, 4), Rect(0, 0, 0.1, 4), Rect(5.9, 0, 6, 4))
    plan = FloorPlan("box", ((0, 0), (6, 0), (6, 4), (0, 4)), walls, (), (Furniture(Rect(2.0, 1.0, 4.0, 3.0), 1.0),))
    cam = DepthCamera(rasterize(plan, 0.05), CameraConfig(noise=None))
    depth = cam.render(CameraPose(1.5, 2.0, 1.5, 0.0, pitch_rad=math.pi / 4))
    # Along the optical axis the hit is 0.5·√2 m away; z-depth equals that distance on the axis.
    assert centre(depth).mean() == pytest.approx(0.5 * math.sqrt(2), abs=0.01)


def test_no_return_beyond_max_depth_or_closer_than_min_depth() -> None:
    walls = (Rect(0, 0, 20, 0.1), Rect(0, 3.9, 20, 4), Rect(0, 0, 0.1, 4), Rect(19.9, 0, 20, 4))
    plan = FloorPlan("hall", ((0, 0), (20, 0), (20, 4), (0, 4)), walls)
    cam = DepthCamera(rasterize(plan, 0.05), CameraConfig(max_depth_m=10.0, noise=None))
    far = cam.render(CameraPose(1.0, 2.0, 1.5, 0.0))
    assert np.all(centre(far) == 0.0)  # the end wall is 18.9 m away
    near = cam.render(CameraPose(0.25, 2.0, 1.5, math.pi))
    assert np.all(centre(near) == 0.0)  # 0.15 m, inside the D435's minimum range


def test_noise_grows_with_square_of_depth_and_drops_pixels() -> None:
    walls = (Rect(0, 0, 8, 0.1), Rect(0, 5.9, 8, 6), Rect(0, 0, 0.1, 6), Rect(7.9, 0, 8, 6))
    plan = FloorPlan("room", ((0, 0), (8, 0), (8, 6), (0, 6)), walls)
    noise = DepthNoise(sigma_per_m=0.004, dropout_fraction=0.05)
    cam = DepthCamera(rasterize(plan, 0.05), CameraConfig(noise=noise))
    rng = np.random.default_rng(1)
    rows = slice(50, 70)  # middle rows see only the wall ahead
    sigmas = {}
    for distance in (1.0, 3.0):
        exact = cam.render(CameraPose(7.9 - distance, 3.0, 1.5, 0.0))[rows]
        noisy = cam.render(CameraPose(7.9 - distance, 3.0, 1.5, 0.0), rng)[rows]
        returned = noisy > 0
        assert 0.03 < 1 - returned.mean() < 0.07  # dropouts
        sigmas[distance] = float(np.std(noisy[returned] - exact[returned]))
        assert sigmas[distance] == pytest.approx(0.004 * distance**2, rel=0.1)
    assert sigmas[3.0] / sigmas[1.0] == pytest.approx(9.0, rel=0.15)
    # Without an rng the render is exact.
    pose = CameraPose(5.9, 3.0, 1.5, 0.0)
    np.testing.assert_array_equal(cam.render(pose), cam.render(pose))
