"""The benchmark flown on the daemon's maps (docs/runtime/README.md, session 38): each step's scan is one depth frame
from the camera the daemon flies with, fused into its voxel maps and projected to its height band (plus the
footprint it stamps free where it has flown), instead of the planar scan. Everything else is `bench explore`'s:
the same starts, planner, predictor, motion model and coverage count. Prints each run's path at 95 % coverage beside
the planar benchmark's run with the same start and seed.

    python docs/runtime/session38/camera_bench.py --plan C --runs 10 --compare docs/bench/policy_bundled.json
"""

import argparse
import json

import cv2
import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.projection import HeightBand, align_to_grid, project
from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion
from edge_explorer.runtime.daemon.config import DaemonConfig, band_z_range_m
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.sim.env import ExplorationEnv
from edge_explorer.world.catalog import load_buildings
from edge_explorer.world.grid import FREE, UNKNOWN


class CameraEnv(ExplorationEnv):
    """`ExplorationEnv` whose sensor is the daemon's depth camera and voxel fusion (one frame a step)."""

    def _sense(self) -> None:
        truth = self._truth
        assert truth is not None and self._maps is not None
        if self._steps == 0:  # a new episode: fresh voxel maps
            self._band = HeightBand()
            self._camera = DepthCamera(truth.raster)
            self._voxels = VoxelMaps(
                VoxelRegion.covering(truth.raster.grid, *band_z_range_m(self._band)), FusionConfig()
            )
            self._flown = np.zeros(truth.raster.grid.shape, np.uint8)
        pose = CameraPose(self._x, self._y, self._band.flight_z_m, self._yaw)
        depth = self._camera.render(pose, self.np_random)
        self._voxels.fuse(depth, self._camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), 0)
        grid = truth.raster.grid
        radius = int(DaemonConfig().footprint_clear_m / grid.resolution_m)
        row, col = grid.cell_of(self._x, self._y)
        cv2.circle(self._flown, (int(col), int(row)), radius, 1, thickness=-1)
        maps = self._maps  # the env's grids: the truth's, which the voxel maps' projections nest in
        high = align_to_grid(*project(self._voxels.high, self._band), maps.high_grid)
        high[(self._flown != 0) & (high == UNKNOWN)] = FREE
        low = align_to_grid(*project(self._voxels.low, self._band), maps.low_grid)
        changed_rows, changed_cols = np.nonzero(high != maps.high)
        self._maps = ObservedMaps(maps.high_grid, maps.low_grid, high, low)
        self._high_inflated.update_cells(high, changed_rows, changed_cols)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="C")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--compare", default="docs/bench/policy_bundled.json")
    args = parser.parse_args()
    raster = load_buildings(args.plan)[0]
    specs = bench.plan_specs([raster], ["drl+pred"], args.runs, 0, predictor="models/predictor", policy="models/policy")
    predictor, policy = bench.load_predictor("models/predictor"), bench.load_policy("models/policy")
    bench.ExplorationEnv = CameraEnv  # run_episode builds its env by this name
    planar = {
        r["spec"]["run"]: r["path_at_coverage_m"]
        for r in json.load(open(args.compare))["runs"]
        if r["spec"]["plan"] == args.plan and r["spec"]["method"] == "drl+pred"
    }
    camera = {}
    for spec in tqdm(specs, desc=f"{args.plan} on the camera's maps"):
        record = bench.run_episode(raster, spec, predictor, policy)
        camera[spec.run] = record["path_at_coverage_m"]
        collisions = record["collisions"]
        print(f"run {spec.run}: camera {camera[spec.run]} m, planar {planar.get(spec.run)} m, collisions {collisions}")
    both = [k for k in camera if camera[k] is not None and planar.get(k) is not None]
    c, p = np.array([camera[k] for k in both]), np.array([planar[k] for k in both])
    d = c - p
    print(
        f"{args.plan}, drl+pred, {len(both)} runs: camera's maps {c.mean():.2f} m, planar {p.mean():.2f} m, "
        f"ratio {c.mean() / p.mean():.3f}, paired {d.mean():+.2f} ± {d.std(ddof=1) / np.sqrt(len(d)):.2f} m"
    )


if __name__ == "__main__":
    main()
