"""Planar sensor (edge_explorer.vehicle.sensor)."""

import math

import numpy as np
import pytest

from edge_explorer.vehicle.sensor import SensorConfig, ray_count, scan
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN
from edge_explorer.world.plan import FloorPlan, Rect
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

NOISE_FREE = SensorConfig(occupied_noise_prob=0.0)


def _empty_room():
    walls = (Rect(0, 0, 6, 0.1), Rect(0, 5.9, 6, 6), Rect(0, 0, 0.1, 6), Rect(5.9, 0, 6, 6))
    return rasterize(FloorPlan("room", ((0, 0), (6, 0), (6, 6), (0, 6)), walls), 0.05)


def _full(raster, patch):
    out = np.zeros(raster.grid.shape, dtype=np.int8)
    out[patch.rows, patch.cols] = patch.codes
    return out


def test_ray_count_leaves_no_gap_at_full_range():
    n = ray_count(SensorConfig(), 0.05)
    assert n == 153
    assert math.radians(87) / (n - 1) * 4.5 / 0.05 < 1.0  # neighbouring rays < 1 cell apart at 4.5 m


def test_every_cell_in_the_field_of_view_is_seen_in_an_open_room():
    room = _empty_room()
    x, y, yaw = 3.02, 2.97, 0.3
    seen = _full(room, scan(room.occupied, room.grid, x, y, yaw, NOISE_FREE))
    rows, cols = np.indices(room.grid.shape)
    cx, cy = room.grid.center_of(rows, cols)
    distance = np.hypot(cx - x, cy - y)
    bearing = np.abs((np.arctan2(cy - y, cx - x) - yaw + np.pi) % (2 * np.pi) - np.pi)
    in_view = (distance < 4.5 - 0.1) & (bearing < math.radians(87) / 2 - 0.02)
    assert (seen[in_view & ~room.occupied & room.interior] == FREE).all()
    assert (seen[in_view & room.occupied] == OCCUPIED).any()
    cell_half_angle = np.arctan2(0.71 * 0.05, distance)  # a ray at the fan's edge still clips cells this far out
    outside_view = (bearing > math.radians(87) / 2 + cell_half_angle + 0.01) | (distance > 4.5 + 0.1)
    assert (seen[outside_view] == UNKNOWN).all()
    assert (seen[room.occupied] != FREE).all() and (~room.occupied[seen == OCCUPIED]).sum() == 0


def test_walls_occlude():
    raster = rasterize(two_room_plan(), 0.05)
    seen = _full(raster, scan(raster.occupied, raster.grid, 1.0, 0.4, 0.0, NOISE_FREE))
    cx, cy = raster.grid.center_of(*np.indices(raster.grid.shape))
    hidden = (cx > 2.1) & (cy < 0.95)  # right room, below every line of sight through the door
    assert (seen[hidden] == UNKNOWN).all()
    assert (seen[(cx > 2.1) & (cy > 2.3)] == FREE).any()  # but the door lets the sensor see part of that room


def test_neighbour_noise():
    raster = rasterize(two_room_plan(), 0.05)
    pose = (1.0, 1.5, 0.2)
    clean = scan(raster.occupied, raster.grid, *pose, NOISE_FREE)
    always = scan(raster.occupied, raster.grid, *pose, SensorConfig(occupied_noise_prob=1.0), np.random.default_rng(0))
    hits = np.argwhere(clean.codes == OCCUPIED)
    for i, j in hits:
        block = always.codes[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2]
        assert (block == OCCUPIED).all()
    false_always = ((always.codes == OCCUPIED) & ~raster.occupied[clean.rows, clean.cols]).sum()
    false_default = [
        (
            (scan(raster.occupied, raster.grid, *pose, SensorConfig(), np.random.default_rng(s)).codes == OCCUPIED)
            & ~raster.occupied[clean.rows, clean.cols]
        ).sum()
        for s in range(20)
    ]
    assert 0.03 < np.mean(false_default) / false_always < 0.5


def test_range_noise_keeps_free_labels_true_and_is_seeded():
    raster = rasterize(two_room_plan(), 0.05)
    config = SensorConfig(range_noise_std_m=0.1)
    a = scan(raster.occupied, raster.grid, 1.0, 1.5, 0.2, config, np.random.default_rng(3))
    b = scan(raster.occupied, raster.grid, 1.0, 1.5, 0.2, config, np.random.default_rng(3))
    clean = scan(raster.occupied, raster.grid, 1.0, 1.5, 0.2, NOISE_FREE)
    np.testing.assert_array_equal(a.codes, b.codes)
    assert not np.array_equal(a.codes, clean.codes)
    assert not raster.occupied[a.rows, a.cols][a.codes == FREE].any()


def test_bad_input():
    raster = rasterize(two_room_plan(), 0.05)
    with pytest.raises(ValueError, match="rng"):
        scan(raster.occupied, raster.grid, 1.0, 1.5, 0.0, SensorConfig())
    with pytest.raises(ValueError, match="outside the grid"):
        scan(raster.occupied, raster.grid, 50.0, 1.5, 0.0, NOISE_FREE)
    with pytest.raises(ValueError, match="fov"):
        SensorConfig(fov_rad=0.0)
    with pytest.raises(ValueError, match="range"):
        SensorConfig(range_m=-1.0)
