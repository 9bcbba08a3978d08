import math

import numpy as np
import pytest

from edge_explorer.mapping.voxels import (
    UNKNOWN_LOGODDS,
    FusionConfig,
    FusionInputError,
    VoxelMaps,
    VoxelRegion,
    depth_to_points,
)
from edge_explorer.vehicle.camera import CameraPose, DepthIntrinsics
from edge_explorer.world.grid import GridSpec

HIT, MISS, CLAMP_MIN, CLAMP_MAX = 847, -405, -1992, 3476  # OctoMap defaults in 1/1000 log-odds
RAW = FusionConfig(endpoint_push_sigmas=0.0, endpoint_push_min_m=0.0)  # endpoints exactly at the returns
REGION = VoxelRegion(origin_xyz_m=(0.0, 0.0, -0.1), size_xyz_m=(8.0, 3.0, 3.4))
ONE_RAY = DepthIntrinsics(1, 1, 100.0, 100.0, 0.0, 0.0)  # a single pixel on the optical axis
# Two pixels in one row, 1e-4 rad apart: practically the same ray.
TWIN_RAYS = DepthIntrinsics(2, 1, 1e4, 1e4, 0.5, 0.0)
POSE = CameraPose(0.52, 1.52, 1.72, yaw_rad=0.0)  # looking along +x, away from voxel faces


def fuse(maps: VoxelMaps, depth, intrinsics=ONE_RAY, pose=POSE, t=None):
    depth = np.asarray(depth, dtype=np.float32).reshape(intrinsics.shape)
    t = maps.frames_fused * 0.1 if t is None else t
    return maps.fuse(depth, intrinsics, pose.position_m, pose.rotation_map_from_optical(), t)


def at(grid, x_m: float, y_m: float = POSE.y_m, z_m: float = POSE.z_m) -> int:
    return int(grid.log_odds[grid.index_of(x_m, y_m, z_m)])


def test_default_parameters_are_octomaps() -> None:
    assert FusionConfig().scaled_logodds() == (HIT, MISS, CLAMP_MIN, CLAMP_MAX, 0)
    assert issubclass(FusionInputError, ValueError)


def test_wall_voxel_occupied_and_ray_free_at_both_resolutions() -> None:
    maps = VoxelMaps(REGION, RAW)
    stats = fuse(maps, [2.0])  # return at x = 2.52
    assert stats.points == 1 and stats.rays_high == 1 and stats.rays_low == 1
    for grid in (maps.high, maps.low):
        assert at(grid, 2.52) == HIT
        assert at(grid, 2.52 + grid.resolution_m) == UNKNOWN_LOGODDS  # behind the surface: unseen
        assert at(grid, POSE.x_m) == MISS  # the camera's own voxel
    for x in np.arange(0.55, 2.5, 0.05):
        assert at(maps.high, x) == MISS
    for x in (0.6, 1.0, 1.5, 2.0, 2.39):
        assert at(maps.low, x) == MISS
    assert np.count_nonzero(maps.high.log_odds != UNKNOWN_LOGODDS) == 41  # x ∈ [0.50, 2.55): 41 voxels


def test_endpoint_push_puts_the_hit_behind_a_surface_on_a_voxel_face() -> None:
    pose = CameraPose(0.5, 1.52, 1.72, 0.0)  # return at x = 2.5 exactly, on a voxel face
    config = FusionConfig()
    push = config.endpoint_push_m(2.0)
    assert push == pytest.approx(4 * 0.002 * 4 + 0.001)
    maps = VoxelMaps(REGION, config)
    fuse(maps, [2.0], pose=pose)
    assert at(maps.high, 2.5 + push) == HIT and 2.5 + push < 2.55  # the voxel [2.50, 2.55) where the wall starts
    assert at(maps.high, 2.49) == MISS
    assert config.endpoint_push_m(10.0) == config.endpoint_push_max_m


def test_returns_beyond_max_range_only_clear_space() -> None:
    maps = VoxelMaps(REGION, RAW)
    fuse(maps, [6.0])  # 6 m return, max range 4.5 m: cut at x = 5.02
    for grid in (maps.high, maps.low):
        assert not np.any(grid.log_odds >= grid.threshold_logodds)
    assert at(maps.high, 4.9) == MISS
    assert at(maps.high, 5.1) == UNKNOWN_LOGODDS
    assert at(maps.high, 6.52) == UNKNOWN_LOGODDS


@pytest.mark.parametrize("bad", [0.0, np.nan, np.inf, -np.inf])
def test_no_return_pixels_fuse_nothing(bad: float) -> None:
    k = DepthIntrinsics.d435(8, 6)
    maps = VoxelMaps(REGION, RAW)
    stats = fuse(maps, np.full(k.shape, bad), intrinsics=k)
    assert stats.points == 0
    assert np.all(maps.high.log_odds == UNKNOWN_LOGODDS) and np.all(maps.low.log_odds == UNKNOWN_LOGODDS)
    assert maps.frames_fused == 1  # a frame of holes is valid input, it just carries no information
    # One good pixel among holes fuses exactly that ray.
    depth = np.full(k.shape, bad)
    depth[3, 4] = 1.0
    assert fuse(maps, depth, intrinsics=k).points == 1


def test_each_voxel_updated_once_per_frame_and_hits_win() -> None:
    maps = VoxelMaps(REGION, RAW)
    fuse(maps, [2.0, 2.0], intrinsics=TWIN_RAYS)  # both returns land in the same voxel
    assert at(maps.high, 2.52) == HIT  # one hit, not two
    assert at(maps.high, 1.5) == MISS  # crossed by two rays, one miss
    maps = VoxelMaps(REGION, RAW)
    fuse(maps, [1.0, 3.0], intrinsics=TWIN_RAYS)  # the long ray passes through the short ray's end voxel
    for grid in (maps.high, maps.low):
        assert at(grid, 1.52) == HIT
        assert at(grid, 3.52) == HIT


def test_log_odds_clamp_at_octomap_bounds() -> None:
    maps = VoxelMaps(REGION, RAW)
    for _ in range(30):
        fuse(maps, [2.0])
    assert at(maps.high, 2.52) == CLAMP_MAX
    assert at(maps.high, 1.5) == CLAMP_MIN


def test_frame_stamps_survive_wraparound() -> None:
    maps = VoxelMaps(REGION, RAW)
    maps._frame = 65533  # the uint16 frame stamps wrap after the next two frames
    for _ in range(4):
        fuse(maps, [2.0])
    assert at(maps.high, 2.52) == 4 * HIT
    assert at(maps.high, 1.5) == 4 * MISS


def test_depth_to_points_follows_the_pinhole_model() -> None:
    k = DepthIntrinsics(4, 2, 2.0, 2.0, 1.5, 0.5)
    depth = np.array([[1.0, 2.0, 0.0, np.nan], [3.0, np.inf, 1.5, 2.5]], dtype=np.float32)
    pose = CameraPose(1.0, 2.0, 1.5, yaw_rad=0.7, pitch_rad=0.1, roll_rad=-0.2)
    rot = pose.rotation_map_from_optical()
    points = depth_to_points(depth, k, pose.position_m, rot, RAW)
    expected = []
    for v, u in [(0, 0), (0, 1), (1, 0), (1, 2), (1, 3)]:
        z = float(depth[v, u])
        expected.append(rot @ [(u - 1.5) / 2.0 * z, (v - 0.5) / 2.0 * z, z] + pose.position_m)
    np.testing.assert_allclose(points, expected, atol=1e-12)


def bad_inputs():
    k = ONE_RAY
    good = np.array([[3.0]], dtype=np.float32)
    rot = POSE.rotation_map_from_optical()
    pos = POSE.position_m
    return {
        "wrong shape": (np.full((2, 2), 3.0, np.float32), pos, rot, 10.0),
        "integer depth": (np.array([[3000]], dtype=np.uint16), pos, rot, 10.0),
        "not an array": ([[3.0]], pos, rot, 10.0),
        "negative depth": (np.array([[-0.5]], dtype=np.float32), pos, rot, 10.0),
        "time going backwards": (good, pos, rot, 0.5),
        "NaN timestamp": (good, pos, rot, math.nan),
        "NaN position": (good, np.array([np.nan, 1.0, 1.7]), rot, 10.0),
        "short position": (good, pos[:2], rot, 10.0),
        "NaN rotation": (good, pos, np.full((3, 3), np.nan), 10.0),
        "scaled rotation": (good, pos, 2.0 * rot, 10.0),
        "reflection": (good, pos, -rot, 10.0),
    }, k


def test_bad_input_raises_before_anything_is_written() -> None:
    maps = VoxelMaps(REGION, RAW)
    fuse(maps, [2.0], t=1.0)
    before = (maps.high.log_odds.tobytes(), maps.low.log_odds.tobytes(), maps.last_timestamp_s, maps.frames_fused)
    cases, k = bad_inputs()
    for name, (depth, position, rotation, t) in cases.items():
        with pytest.raises(FusionInputError):
            maps.fuse(depth, k, position, rotation, t)
        after = (maps.high.log_odds.tobytes(), maps.low.log_odds.tobytes(), maps.last_timestamp_s, maps.frames_fused)
        assert after == before, name
    # The maps still work, and an equal timestamp is fine.
    fuse(maps, [3.0], t=1.0)
    assert at(maps.high, 3.52) == HIT


def test_region_nests_with_plan_grids() -> None:
    grid = GridSpec((-0.4, -0.4), 0.05, (223, 385))
    region = VoxelRegion.covering(grid, z_max_m=3.1)
    maps = VoxelMaps(region)
    assert maps.high.grid.origin_xy == grid.origin_xy == maps.low.grid.origin_xy
    assert maps.high.shape[:2] == (224, 388) and maps.low.shape[:2] == grid.coarsened(4).shape
    assert maps.high.layer_centers_m()[0] == pytest.approx(-0.075)
    with pytest.raises(ValueError, match="multiple"):
        VoxelRegion(size_xyz_m=(24.1, 14.0, 3.4)).shape_at(0.2)
    with pytest.raises(ValueError):
        FusionConfig(prob_hit=0.4)
    with pytest.raises(ValueError):
        FusionConfig(endpoint_push_max_m=-0.1)
