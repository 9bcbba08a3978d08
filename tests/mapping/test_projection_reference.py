"""The vectorised projection kernel against the branchy one it replaced: the same codes, cell for cell.

:func:`reference_kernel` is the kernel as it was before the speed-up (a branch per voxel: unknown, free or
occupied, stopping at the first occupied one); the shipped kernel takes a column's maximum over the band and its
minimum below flight height. Fused maps of the two-room plan (both resolutions, several bands) and random log-odds
with the edge values (unknown, the threshold and one below it, the int16 extremes) exercise every branch.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import UNKNOWN_LOGODDS, FusionConfig, VoxelGrid, VoxelMaps, VoxelRegion
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

BANDS = (HeightBand(), HeightBand(1.0, 2.0, 1.7), HeightBand(1.55, 1.9, 1.6), HeightBand(0.0, 3.3, 0.05))


@numba.njit(cache=True)
def reference_kernel(log_odds, first, count, below_flight, threshold, unknown, codes):
    rows, cols = codes.shape
    for i in range(rows):
        for j in range(cols):
            occupied = False
            seen_below = True
            for k in range(count):
                v = log_odds[i, j, first + k]
                if v == unknown:
                    if below_flight[k]:
                        seen_below = False
                elif v >= threshold:
                    occupied = True
                    break
            codes[i, j] = OCCUPIED if occupied else (FREE if seen_below else UNKNOWN)


def reference_project(voxels: VoxelGrid, band: HeightBand) -> np.ndarray:
    z = voxels.layer_centers_m()
    layers = band.layers(z)
    below_flight = (z[layers] - voxels.resolution_m / 2) < band.flight_z_m
    codes = np.empty(voxels.shape[:2], dtype=CELL_DTYPE)
    first = int(layers[0]) if len(layers) else 0
    args = (voxels.log_odds, first, len(layers), below_flight, voxels.threshold_logodds, UNKNOWN_LOGODDS, codes)
    reference_kernel(*args)
    return codes


@pytest.fixture(scope="module")
def fused_maps() -> VoxelMaps:
    """The two-room plan seen from a spin in each room (noisy depth, as the daemon's camera)."""
    raster = rasterize(two_room_plan(), 0.05)
    camera = DepthCamera(raster)
    maps = VoxelMaps(VoxelRegion.covering(raster.grid), FusionConfig())
    rng = np.random.default_rng(3)
    for t, (x, y, yaw) in enumerate(
        (x, y, yaw) for x, y in ((1.0, 1.5), (3.0, 2.0)) for yaw in np.linspace(0, 2 * math.pi, 8, endpoint=False)
    ):
        pose = CameraPose(x, y, 1.7, float(yaw))
        maps.fuse(
            camera.render(pose, rng), camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), t
        )
    return maps


@pytest.mark.parametrize("band", BANDS)
def test_fused_maps_project_as_before(fused_maps: VoxelMaps, band: HeightBand) -> None:
    for voxels in (fused_maps.high, fused_maps.low):
        codes, _ = project(voxels, band)
        expected = reference_project(voxels, band)
        np.testing.assert_array_equal(codes, expected)
    # The maps hold all three outcomes under the default band, so every branch was compared.
    assert set(np.unique(project(fused_maps.high)[0])) == {FREE, UNKNOWN, OCCUPIED}


@pytest.mark.parametrize("threshold", [0, -500, 1200])
def test_random_log_odds_with_edge_values_project_as_before(threshold: int) -> None:
    rng = np.random.default_rng(threshold + 1000)
    voxels = VoxelGrid(VoxelRegion((0.0, 0.0, -0.1), (3.0, 2.0, 3.4)), 0.05, threshold_logodds=threshold)
    info = np.iinfo(np.int16)
    edge = np.array([UNKNOWN_LOGODDS, threshold, threshold - 1, info.max, info.min + 1, -2000], dtype=np.int16)
    values = np.where(
        rng.random(voxels.shape) < 0.5, rng.choice(edge, voxels.shape), rng.integers(-2000, 2000, voxels.shape)
    )
    # Mostly-unknown and mostly-known columns both occur; a few columns entirely unknown or entirely free.
    unknown = rng.random(voxels.shape) < rng.random(voxels.shape[:2])[..., np.newaxis]
    voxels.log_odds[...] = np.where(unknown, UNKNOWN_LOGODDS, values).astype(np.int16)
    voxels.log_odds[0, :5] = UNKNOWN_LOGODDS
    voxels.log_odds[1, :5] = min(threshold - 1, -1)
    for band in BANDS:
        np.testing.assert_array_equal(project(voxels, band)[0], reference_project(voxels, band))
    assert set(np.unique(project(voxels)[0])) == {FREE, UNKNOWN, OCCUPIED}


def test_a_region_below_the_band_projects_as_before() -> None:
    """No layer in the band: every column is FREE under the rule (nothing occupied, nothing unseen below)."""
    voxels = VoxelGrid(VoxelRegion((0.0, 0.0, -0.1), (0.5, 0.5, 1.0)), 0.05)
    codes = project(voxels)[0]
    np.testing.assert_array_equal(codes, reference_project(voxels, HeightBand()))
    assert np.all(codes == FREE)
