import numpy as np
import pytest

from edge_explorer.errors import PlanError
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.raster import check_connected, clearance_m, rasterize
from tests.conftest import two_room_plan


def test_grid_cell_convention():
    grid = GridSpec((1.0, 2.0), 0.5, (4, 6))
    row, col = grid.cell_of(1.74, 2.26)
    assert (row, col) == (0, 1)
    x, y = grid.center_of(row, col)
    assert (x, y) == (1.75, 2.25)
    with pytest.raises(ValueError, match="positive"):
        GridSpec((0, 0), 0.0, (1, 1))


def test_rasterize_marks_walls_doors_and_furniture(plan):
    r = rasterize(plan, 0.05)
    row, col = r.grid.cell_of(np.array([2.0, 2.0, 1.0, 0.4, 3.1]), np.array([0.5, 1.5, 1.5, 2.6, 0.9]))
    # divider wall, door gap, open floor, tall cabinet, low table
    assert r.occupied[row[0], col[0]]
    assert not r.occupied[row[1], col[1]]
    assert r.height_m[row[2], col[2]] == 0.0
    assert r.occupied[row[3], col[3]] and r.height_m[row[3], col[3]] == pytest.approx(1.8)
    assert not r.occupied[row[4], col[4]] and r.height_m[row[4], col[4]] == pytest.approx(0.75)
    truth = r.truth_codes()
    assert truth[row[1], col[1]] == FREE and truth[row[0], col[0]] == OCCUPIED and truth[0, 0] == UNKNOWN
    # interior: the 4 m × 3 m outline, walls included
    assert r.interior.sum() * 0.05**2 == pytest.approx(12.0, rel=0.02)


def test_thin_walls_survive_coarse_resolution(plan):
    r = rasterize(plan, 0.20)
    row, col = r.grid.cell_of(2.0, 0.5)
    assert r.occupied[row, col]
    row, col = r.grid.cell_of(2.0, 1.5)
    assert not r.occupied[row, col]  # the 1 m door stays open at 0.2 m


def test_coarsened_nests_with_direct_grid(plan):
    fine = rasterize(plan, 0.05)
    coarse = fine.coarsened(0.20)
    assert coarse.grid.origin_xy == fine.grid.origin_xy
    assert coarse.grid.resolution_m == pytest.approx(0.20)
    # every occupied fine cell lies in an occupied coarse cell
    rows, cols = np.nonzero(fine.occupied)
    assert coarse.occupied[rows // 4, cols // 4].all()


def test_connectivity_rule(plan):
    check_connected(rasterize(plan, 0.05))
    with pytest.raises(PlanError, match="split into 2 regions"):
        check_connected(rasterize(two_room_plan(door=False), 0.05))


def test_clearance_is_distance_to_wall_edge(plan):
    r = rasterize(plan, 0.05)
    row, col = r.grid.cell_of(1.0, 1.0)
    # nearest walls: x = 0.1 (0.9 m away) and y = 0.1 (0.9 m away); divider at 1.95 (0.95 m)
    assert clearance_m(r)[row, col] == pytest.approx(0.875, abs=0.06)


def test_coarse_interior_leaves_out_unseeable_slivers_of_perimeter_walls():
    """A 4.1 m wide building: at 0.20 m the cells that straddle the outer face of the east wall hold only a
    sliver of wall no sensor inside can see; they are not interior, while every interior coarse cell holds a
    free cell or a wall face."""
    from scipy import ndimage

    from edge_explorer.world.plan import FloorPlan, Rect

    walls = (Rect(0, 0, 4.1, 0.1), Rect(0, 2.9, 4.1, 3.0), Rect(0, 0, 0.1, 3.0), Rect(3.95, 0, 4.1, 3.0))
    plan = FloorPlan("odd-width", ((0, 0), (4.1, 0), (4.1, 3.0), (0, 3.0)), walls)
    fine = rasterize(plan, 0.05)
    coarse = fine.coarsened(0.20)
    free = fine.interior & ~fine.occupied
    seeable = free | (fine.occupied & ndimage.binary_dilation(free))
    rows, cols = np.nonzero(coarse.interior)
    for i, j in zip(rows, cols, strict=True):
        assert seeable[4 * i : 4 * i + 4, 4 * j : 4 * j + 4].any(), (i, j)
    assert coarse.interior.sum() * 0.04 == pytest.approx(4.1 * 3.0, rel=0.05)
