"""One view, two sensors (docs/runtime/README.md, session 38): from the same pose, what one planar scan (the
benchmark's sensor, noise off) and one depth frame (fused into the daemon's voxel maps and projected to its height
band) each observe, counted on the 0.20 m grid that coverage is counted on.

    python docs/runtime/session38/one_view.py C --poses 40

Poses: uniform over the building's interior, at least 0.5 m from any wall, uniform yaw, seeded. Prints the mean
number of low-res cells each sensor observes per view, how many both observe, and where (distance from the pose)
the cells seen by only one of them lie.
"""

import argparse

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.vehicle.sensor import SensorConfig, scan
from edge_explorer.world.catalog import load_buildings
from edge_explorer.world.grid import LOW_RES_M, UNKNOWN

DISTANCE_BINS_M = (0.0, 1.0, 2.0, 3.0, 4.0, 4.5, 6.0)


def free_pose(raster, occupied: np.ndarray, rng: np.random.Generator, clearance_m: float = 0.5):
    """A uniform interior pose whose cell is at least ``clearance_m`` from every occupied cell (square window)."""
    cells = np.argwhere(raster.interior)
    w = int(round(clearance_m / raster.grid.resolution_m))
    while True:
        r, c = (int(v) for v in cells[rng.integers(len(cells))])
        if not occupied[max(r - w, 0) : r + w + 1, max(c - w, 0) : c + w + 1].any():
            x_m, y_m = raster.grid.center_of(r, c)
            return float(x_m), float(y_m), float(rng.uniform(-np.pi, np.pi))


def distances_m(mask: np.ndarray, grid, x_m: float, y_m: float) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    centres = np.array([grid.center_of(r, c) for r, c in zip(rows, cols, strict=True)]).reshape(-1, 2)
    return np.hypot(centres[:, 0] - x_m, centres[:, 1] - y_m)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plan", help="a bundled building: A, B, C or D")
    parser.add_argument("--poses", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    raster = load_buildings(args.plan)[0]
    occupied = raster.occupied
    band = HeightBand()
    camera = DepthCamera(raster)
    region = VoxelRegion.covering(raster.grid, *band_z_range_m(band))
    rng = np.random.default_rng(args.seed)
    counts, planar_only, camera_only = [], [], []
    for _ in range(args.poses):
        x_m, y_m, yaw = free_pose(raster, occupied, rng)
        maps = ObservedMaps.empty(raster.grid, LOW_RES_M)
        patch = scan(occupied, raster.grid, x_m, y_m, yaw, SensorConfig(occupied_noise_prob=0.0, range_noise_std_m=0.0))
        maps.apply_patch(patch.row0, patch.col0, patch.codes)
        planar = maps.low != UNKNOWN
        voxels = VoxelMaps(region, FusionConfig())
        pose = CameraPose(x_m, y_m, band.flight_z_m, yaw)
        voxels.fuse(camera.render(pose), camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), 0)
        low, low_grid = project(voxels.low, band)
        seen = low != UNKNOWN
        counts.append((planar.sum(), seen.sum(), (planar & seen).sum()))
        planar_only.append(distances_m(planar & ~seen, low_grid, x_m, y_m))
        camera_only.append(distances_m(seen & ~planar, low_grid, x_m, y_m))
    planar_n, camera_n, both_n = np.mean(counts, axis=0)
    per_view = f"planar {planar_n:.1f}, camera {camera_n:.1f}, both {both_n:.1f}"
    print(f"{args.plan}: {args.poses} poses; low cells observed per view: {per_view}")
    for label, values in (("planar only", planar_only), ("camera only", camera_only)):
        histogram, _ = np.histogram(np.concatenate(values), bins=DISTANCE_BINS_M)
        edges = zip(DISTANCE_BINS_M[:-1], DISTANCE_BINS_M[1:], histogram, strict=True)
        bins = ", ".join(f"{a:g}-{b:g} m: {n}" for a, b, n in edges)
        print(f"  {label} cells by distance from the pose (all views): {bins}")


if __name__ == "__main__":
    main()
