import math

import numpy as np
import pytest

from edge_explorer.mapping.projection import HeightBand, align_to_grid, onto_grid, project, project_box
from edge_explorer.mapping.voxels import UNKNOWN_LOGODDS, FusionConfig, VoxelGrid, VoxelMaps, VoxelRegion
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraConfig, CameraPose
from edge_explorer.world.grid import FREE, LOW_RES_M, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

OCC_L, FREE_L = 2000, -1000  # log-odds (1/1000) of an occupied and a free voxel


def test_column_rule() -> None:
    vox = VoxelGrid(VoxelRegion((0.0, 0.0, -0.1), (0.4, 0.4, 3.4)), 0.05)
    z = vox.layer_centers_m()
    band = (z >= 1.5) & (z < 2.5)
    lo = vox.log_odds
    lo[0, 0, band] = FREE_L
    lo[0, 0, (z > 0.9) & (z < 1.1)] = OCC_L  # low furniture below the band: ignored
    lo[0, 1, band] = FREE_L
    lo[0, 1, (z > 1.95) & (z < 2.05)] = OCC_L  # obstacle in the band
    lo[0, 2, band] = FREE_L
    lo[0, 2, z > 2.7] = OCC_L  # ceiling band: ignored
    lo[0, 3, band & (z > 1.7)] = FREE_L  # seen only above flight height (over a tall cabinet): not free
    lo[0, 5, band & (z < 1.7)] = FREE_L
    lo[0, 5, np.argmin(abs(z - 1.575))] = UNKNOWN_LOGODDS  # one unseen layer below flight height
    lo[0, 6, band & (z < 1.7)] = FREE_L  # everything up to flight height seen: free
    codes, grid = project(vox)
    assert codes.dtype == np.int8 and grid == vox.grid
    assert list(codes[0, :7]) == [FREE, OCCUPIED, FREE, UNKNOWN, UNKNOWN, UNKNOWN, FREE]
    assert np.all(codes[1:] == UNKNOWN)


def test_project_box_updates_its_box_alone() -> None:
    """A box's cells come out as a whole projection gives them; cells outside keep what they held (a map that
    knows where its voxels changed reprojects only there); a box past the edge is clipped; codes of another shape
    are refused."""
    vox = VoxelGrid(VoxelRegion((0.0, 0.0, -0.1), (0.4, 0.4, 3.4)), 0.05)
    z = vox.layer_centers_m()
    vox.log_odds[:, :, (z >= 1.5) & (z < 2.5)] = FREE_L
    vox.log_odds[2:4, 2:4, np.argmin(abs(z - 2.0))] = OCC_L
    codes = np.full(vox.shape[:2], 7, dtype=np.int8)
    project_box(vox, HeightBand(), codes, (1, 3), (2, 20))
    whole, _ = project(vox)
    np.testing.assert_array_equal(codes[1:3, 2:], whole[1:3, 2:])
    assert list(codes[1:3, 2:4].ravel()) == [FREE, FREE, OCCUPIED, OCCUPIED]
    outside = np.ones(codes.shape, dtype=bool)
    outside[1:3, 2:] = False
    assert np.all(codes[outside] == 7)
    with pytest.raises(ValueError, match="do not hold the columns"):
        project_box(vox, HeightBand(), codes[1:], (0, 1), (0, 1))


def test_height_band_must_contain_flight_height() -> None:
    with pytest.raises(ValueError):
        HeightBand(min_z_m=1.5, max_z_m=2.5, flight_z_m=2.6)


def test_align_to_grid_crops_and_pads() -> None:
    grid = GridSpec((0.0, 0.0), 0.2, (3, 4))
    codes = np.arange(12, dtype=np.int8).reshape(3, 4)
    out = align_to_grid(codes, grid, GridSpec((0.2, -0.2), 0.2, (3, 3)))
    np.testing.assert_array_equal(out, [[UNKNOWN] * 3, [1, 2, 3], [5, 6, 7]])
    with pytest.raises(ValueError, match="resolution"):
        align_to_grid(codes, grid, GridSpec((0.0, 0.0), 0.05, (3, 3)))
    with pytest.raises(ValueError, match="whole cells"):
        align_to_grid(codes, grid, GridSpec((0.1, 0.0), 0.2, (3, 3)))


def test_onto_grid_nests_when_it_can_and_else_takes_the_nearest_cell() -> None:
    """A grown map's grid need not nest with a plan's: each target cell then takes the code under its centre."""
    codes = np.arange(12, dtype=np.int8).reshape(3, 4)
    grid = GridSpec((0.0, 0.0), 0.2, (3, 4))
    nested = GridSpec((0.2, -0.2), 0.2, (3, 3))
    np.testing.assert_array_equal(onto_grid(codes, grid, nested), align_to_grid(codes, grid, nested))
    shifted = onto_grid(codes, grid, GridSpec((0.15, 0.05), 0.2, (3, 4)))  # centres at x 0.25, 0.45 …
    np.testing.assert_array_equal(shifted[0], [1, 2, 3, UNKNOWN])
    np.testing.assert_array_equal(shifted[2], [9, 10, 11, UNKNOWN])


@pytest.fixture(scope="module")
def mapped_two_rooms():
    """The two-room plan mapped from a spin in each room (exact depth), projected at both resolutions."""
    raster = rasterize(two_room_plan(), 0.05)
    camera = DepthCamera(raster, CameraConfig(noise=None))
    maps = VoxelMaps(VoxelRegion.covering(raster.grid), FusionConfig())
    k = camera.config.intrinsics
    t = 0.0
    for x, y in ((1.0, 1.5), (3.0, 2.0), (2.8, 1.9)):
        for yaw in np.linspace(0, 2 * math.pi, 16, endpoint=False):
            pose = CameraPose(x, y, 1.7, float(yaw))
            maps.fuse(camera.render(pose), k, pose.position_m, pose.rotation_map_from_optical(), t)
            t += 0.1
    low = raster.coarsened(LOW_RES_M)
    out = {}
    for vox, truth in ((maps.high, raster), (maps.low, low)):
        codes, grid = project(vox)
        out[vox.resolution_m] = (align_to_grid(codes, grid, truth.grid), truth)
    return out


def cells(truth, x0: float, y0: float, x1: float, y1: float) -> tuple[slice, slice]:
    """Index slices of the truth grid's cells covering [x0, x1) × [y0, y1)."""
    (ox, oy), r = truth.grid.origin_xy, truth.grid.resolution_m
    return slice(round((y0 - oy) / r), round((y1 - oy) / r)), slice(round((x0 - ox) / r), round((x1 - ox) / r))


@pytest.mark.parametrize("res", [0.05, 0.20])
def test_projection_marks_tall_cabinet_and_ignores_low_table(mapped_two_rooms, res: float) -> None:
    codes, truth = mapped_two_rooms[res]
    # Tall cabinet (1.8 m) on x ∈ [0.1, 0.7], y ∈ [2.4, 2.9]: its cells are occupied, never free.
    cabinet = codes[cells(truth, 0.2, 2.4, 0.6, 2.8)]
    assert np.any(cabinet == OCCUPIED) and not np.any(cabinet == FREE)
    assert np.all(codes[cells(truth, 0.2, 2.4, 0.6, 2.4 + res)] == OCCUPIED)  # its south face row
    # Low table (0.75 m) on x ∈ [2.8, 3.4], y ∈ [0.6, 1.2]: below the band, so free floor in the 2-D map.
    table = codes[cells(truth, 2.8, 0.6, 3.4, 1.2)]
    assert np.all(table == FREE)
    # The divider wall beside the door is occupied.
    assert np.all(codes[cells(truth, 2.0, 2.2, 2.0 + res, 2.6)] == OCCUPIED)


@pytest.mark.parametrize("res", [0.05, 0.20])
def test_projected_cells_line_up_with_ground_truth(mapped_two_rooms, res: float) -> None:
    codes, truth = mapped_two_rooms[res]
    assert codes.shape == truth.grid.shape
    observed = truth.interior & (codes != UNKNOWN)
    assert observed.sum() > 0.8 * truth.interior.sum()
    correct = (codes == truth.truth_codes())[observed].mean()
    assert correct > 0.97
