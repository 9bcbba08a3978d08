"""Maps that grow (mapping/growing.py): past any preset box, exactly as one large fixed box, in bounded memory."""

import math

import numpy as np
import pytest

from edge_explorer.mapping.growing import GrowingMaps, GrowthConfig, footprint_bound
from edge_explorer.mapping.projection import HeightBand, align_to_grid, project
from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.vehicle.camera import CameraPose, DepthIntrinsics
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN

Z_RANGE = (1.3, 2.7)  # the daemon's: band_z_range_m(HeightBand())
CAMERA = DepthIntrinsics.from_fov(64, 48, math.radians(87), math.radians(58))
HALF_WIDTH_M = 1.5  # a corridor along +x, walls at y = ±1.5 m, floor 0, ceiling 3 m; a door-less end wall at x_end


def corridor_depth(pose: CameraPose, x_end_m: float = 1e9) -> np.ndarray:
    """The z-depth image of the corridor seen from ``pose`` (no return beyond 10 m)."""
    xn, yn = CAMERA.normalized_coords()
    rays = np.stack(np.broadcast_arrays(xn[None, :], yn[:, None], np.ones((1, 1))), axis=-1)  # optical, z = 1
    d = rays @ pose.rotation_map_from_optical().T  # map-frame direction per unit z-depth
    p = pose.position_m
    depth = np.full(CAMERA.shape, np.inf)
    for axis, planes in ((1, (-HALF_WIDTH_M, HALF_WIDTH_M)), (2, (0.0, 3.0)), (0, (x_end_m,))):
        for plane in planes:
            with np.errstate(divide="ignore", invalid="ignore"):
                z = (plane - p[axis]) / d[..., axis]
            depth = np.where((z > 0) & (z < depth), z, depth)
    depth[depth > 10.0] = np.inf
    return depth.astype(np.float32)


def fly(maps: VoxelMaps, xs: np.ndarray, yaw: float = 0.0) -> None:
    for i, x in enumerate(xs):
        pose = CameraPose(float(x), 0.03, 1.7, yaw)
        maps.fuse(corridor_depth(pose), CAMERA, pose.position_m, pose.rotation_map_from_optical(), 0.1 * i)


def test_the_maps_grow_past_any_preset_box_and_keep_what_they_saw():
    """60 m along a corridor: far past the first box (16 m) and the old default (24 m × 14 m); the 2-D maps cover
    the whole way, and what was seen near the start is still there at the end."""
    maps = GrowingMaps(0.0, 0.0, Z_RANGE)
    first = maps.grid
    assert first.size_xy_m[0] <= 16.2
    fly(maps, np.arange(0.0, 60.0, 0.5))
    high, high_grid, low, low_grid = maps.project()
    assert maps.growths >= 2 and maps.recentrings >= 2
    assert high_grid.size_xy_m[0] >= 60.0 and low_grid.size_xy_m[0] >= 60.0
    for x in (6.0, 20.0, 40.0, 59.0):  # the corridor's walls and its free middle, all along
        for grid, codes in ((high_grid, high), (low_grid, low)):
            row, col = grid.cell_of(x, 0.6)
            assert codes[row, col] == FREE, (x, grid.resolution_m)
            row, col = grid.cell_of(x, HALF_WIDTH_M + 0.01)
            assert codes[row, col] == OCCUPIED, (x, grid.resolution_m)
    assert (high == UNKNOWN).any()  # beyond the walls nothing was seen
    assert high_grid.shape == (low_grid.shape[0] * 4, low_grid.shape[1] * 4)
    assert high_grid.origin_xy == low_grid.origin_xy


def _same_as_one_fixed_box(xs: np.ndarray) -> tuple[GrowingMaps, VoxelMaps]:
    grown = GrowingMaps(0.0, 0.0, Z_RANGE, growth=GrowthConfig(window_m=12.0))
    fly(grown, xs)
    # One big box on the same lattice (its voxel coordinates counted from the same anchor, the take-off point).
    fixed = VoxelMaps(VoxelRegion((0.0, 0.0, Z_RANGE[0]), (0.2, 0.2, 1.4)))
    fixed.low.reframe(-120, -120, 240, 400)  # x, y from -24 m: 80 m × 48 m
    fixed.high.reframe(-480, -480, 960, 1600)
    fly(fixed, xs)
    assert grown.growths >= 1 and grown.recentrings >= 2
    # The 0.20 m map: every voxel of the grown box equals the fixed box's, and so does its projection.
    r0, c0, _ = fixed.low.index_of(*grown.low.grid.origin_xy, Z_RANGE[0] + 0.01)
    rows, cols, _ = grown.low.shape
    assert r0 >= 0 and c0 >= 0 and r0 + rows <= fixed.low.shape[0] and c0 + cols <= fixed.low.shape[1]
    np.testing.assert_array_equal(grown.low.log_odds, fixed.low.log_odds[r0 : r0 + rows, c0 : c0 + cols])
    _, _, low, low_grid = grown.project()
    np.testing.assert_array_equal(low, align_to_grid(*project(fixed.low, HeightBand()), low_grid))
    return grown, fixed


def test_fusion_is_unchanged_by_growth_and_by_the_window_moving():
    """Flying on along a corridor: the maps grew and the 0.05 m window moved, yet they hold exactly what one big
    fixed box fused from the same frames holds (voxel coordinates count from one anchor: bit-for-bit the same
    rays) — the window over its box, the 2-D 0.05 m map everywhere (what left the window survives in it)."""
    grown, fixed = _same_as_one_fixed_box(np.arange(0.0, 30.0, 0.5))
    r0, c0, _ = fixed.high.index_of(*grown.high.grid.origin_xy, Z_RANGE[0] + 0.01)
    rows, cols, _ = grown.high.shape
    np.testing.assert_array_equal(grown.high.log_odds, fixed.high.log_odds[r0 : r0 + rows, c0 : c0 + cols])
    high, high_grid, _, _ = grown.project()
    np.testing.assert_array_equal(high, align_to_grid(*project(fixed.high, HeightBand()), high_grid))


def test_what_left_the_window_survives_a_way_back():
    """Out and back: the 0.20 m map is still exactly the fixed box's; at 0.05 m the cells seen again start from
    fresh 3-D evidence, so a few may differ, but nothing seen is lost."""
    grown, fixed = _same_as_one_fixed_box(np.concatenate([np.arange(0.0, 30.0, 0.5), np.arange(30.0, 2.0, -0.5)]))
    high, high_grid, _, _ = grown.project()
    fixed_high = align_to_grid(*project(fixed.high, HeightBand()), high_grid)
    known = fixed_high != UNKNOWN
    assert np.mean(high[known] == fixed_high[known]) > 0.99
    assert np.count_nonzero(high != UNKNOWN) >= np.count_nonzero(known)


def test_fusion_cost_does_not_depend_on_the_maps_size():
    """A frame fused into a map that grew over 120 m costs what it costs in a fresh one (same frame, same rays)."""
    import time

    fresh = GrowingMaps(0.0, 0.0, Z_RANGE)
    grown = GrowingMaps(0.0, 0.0, Z_RANGE)
    fly(grown, np.arange(0.0, 120.0, 2.0))
    assert grown.low.log_odds.size > 8 * fresh.low.log_odds.size
    pose_fresh, pose_grown = CameraPose(0.5, 0.03, 1.7, 0.0), CameraPose(118.5, 0.03, 1.7, 0.0)

    def cost(maps: GrowingMaps, pose: CameraPose) -> float:
        depth = corridor_depth(pose)
        t = maps.last_timestamp_s or 0.0
        best = math.inf
        for i in range(15):
            start = time.perf_counter()
            maps.fuse(depth, CAMERA, pose.position_m, pose.rotation_map_from_optical(), t + 0.1 * (i + 1))
            best = min(best, time.perf_counter() - start)
        return best

    cost(fresh, pose_fresh)  # compiled and warm
    assert cost(grown, pose_grown) < 3 * cost(fresh, pose_fresh) + 2e-4


def test_the_memory_footprint_is_bounded_and_fits_a_whole_floor():
    """A long zig-zag flight stays within the analytic bound for its extent; that bound for a 270 m × 60 m floor
    leaves the daemon's 300 MB budget most of its room (the rest of the daemon peaks at ~150 MB)."""
    maps = GrowingMaps(0.0, 0.0, Z_RANGE)
    for leg, y in enumerate((0.0, 12.0, 24.0)):
        xs = np.arange(0.0, 80.0, 2.0) if leg % 2 == 0 else np.arange(80.0, 0.0, -2.0)
        for i, x in enumerate(xs):
            pose = CameraPose(float(x), y, 1.7, 0.0)
            t = (maps.last_timestamp_s or 0.0) + 0.1
            maps.fuse(corridor_depth(pose), CAMERA, pose.position_m, pose.rotation_map_from_optical(), t)
            if i % 10 == 0:
                assert maps.nbytes() <= footprint_bound((80.0, 24.0), Z_RANGE)
    assert maps.nbytes() <= footprint_bound((80.0, 24.0), Z_RANGE)
    floor_mb = footprint_bound((270.0, 60.0), Z_RANGE) / 1e6
    assert floor_mb < 150.0, floor_mb
    # Dense 0.05 m voxels over the floor would need ~0.7 GB: that is what the window saves.
    assert 5400 * 1200 * 28 * 4 / 1e6 > 4 * floor_mb


def test_the_flown_footprint_grows_with_the_maps():
    maps = GrowingMaps(0.0, 0.0, Z_RANGE)
    maps.mark_flown(0.0, 0.0, 0.2)
    fly(maps, np.arange(0.0, 40.0, 1.0))
    maps.mark_flown(39.0, 0.0, 0.2)
    high, grid, _, _ = maps.project()
    for x in (0.0, 39.0):
        assert maps.flown[grid.cell_of(x, 0.0)] == 1 and high[grid.cell_of(x, 0.0)] == FREE


def test_a_window_too_small_for_the_sensor_is_refused():
    with pytest.raises(ValueError, match="window"):
        GrowingMaps(0.0, 0.0, Z_RANGE, growth=GrowthConfig(window_m=8.0))


def test_each_projection_equals_a_whole_composition_while_the_maps_grow_and_the_window_moves():
    """project() reprojects only where frames wrote and composes only there and the newly flown cells between
    calls; at every call both maps equal the seen map, the window and the footprint projected and composed whole,
    and the 0.20 m map projected whole, through growths, moves of the window and flights back over flown cells."""
    maps = GrowingMaps(0.0, 0.0, Z_RANGE)
    xs = np.concatenate([np.arange(0.0, 30.0, 0.5), np.arange(30.0, 10.0, -0.5)])
    recentrings = []
    for i, x in enumerate(xs):
        pose = CameraPose(float(x), 0.03, 1.7, 0.0 if i < 60 else math.pi)
        maps.fuse(corridor_depth(pose), CAMERA, pose.position_m, pose.rotation_map_from_optical(), 0.1 * i)
        maps.mark_flown(float(x), 0.03, 0.2)
        if i % 3:
            continue
        recentrings.append(maps.recentrings)
        high, grid, low, low_grid = maps.project()
        np.testing.assert_array_equal(low, project(maps.low, HeightBand())[0])
        assert low_grid == maps.low.grid
        window, window_grid = project(maps.high, HeightBand())
        expected = maps.seen.copy()
        laid = align_to_grid(window, window_grid, grid)
        expected[laid != UNKNOWN] = laid[laid != UNKNOWN]
        expected[(expected == UNKNOWN) & (maps.flown != 0)] = FREE
        np.testing.assert_array_equal(high, expected)
    assert maps.growths >= 1 and maps.recentrings >= 2
    assert sum(a == b for a, b in zip(recentrings, recentrings[1:], strict=False)) > 10  # in place, mostly
