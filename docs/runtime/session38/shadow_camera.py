"""The benchmark's own flights, seen a second time by the daemon's camera (docs/runtime/README.md, session 38).

Flies the benchmark's drl+pred runs of one building exactly as `bench explore` does (planar sensor, one scan per
1 s step), and after every step also renders one depth frame from the same pose into a shadow of the daemon's voxel
maps. Per step it records the path and the observed coverage (DESIGN.md §7's N_M, prediction left out) of the
planar map the run flies on and of the shadow map. Equal curves mean that the same flight observes the same with
either sensor, so the daemon's shorter flights of C come from where and how often it looks, not from its camera.
``--frames-per-step K`` fuses K frames a step instead of one, the extra ones at poses interpolated along the step
(the daemon fuses depth at 15 Hz while it flies; at 2 Hz it flew C as short, session 33).

    python docs/runtime/session38/shadow_camera.py --plan C --runs 10 --frames-per-step 1
"""

import argparse

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.runtime.daemon.report import CoverageTruth
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.sim.env import ExplorationEnv
from edge_explorer.world.catalog import load_buildings

PATHS_M = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)


class ShadowCameraEnv(ExplorationEnv):
    """`ExplorationEnv` (planar sensor, unchanged) that also fuses camera frames into a shadow of the daemon's maps
    and keeps one row per step: (path m, planar observed coverage, camera observed coverage)."""

    frames_per_step = 1

    def _sense(self) -> None:
        super()._sense()
        truth = self._truth
        assert truth is not None
        if self._steps == 0:  # a new episode
            self._band, self._camera = HeightBand(), DepthCamera(truth.raster)
            self._coverage = CoverageTruth(truth.raster)
            region = VoxelRegion.covering(truth.raster.grid, *band_z_range_m(self._band))
            self._shadow, self._before, self._frames, self.rows = VoxelMaps(region, FusionConfig()), None, 0, []
        before = self._before or (self._x, self._y, self._yaw)
        turn = (self._yaw - before[2] + np.pi) % (2 * np.pi) - np.pi
        for k in range(1, self.frames_per_step + 1):  # the last frame at the step's end pose, the others on the way
            f = k / self.frames_per_step
            x_m, y_m = before[0] + f * (self._x - before[0]), before[1] + f * (self._y - before[1])
            pose = CameraPose(x_m, y_m, self._band.flight_z_m, before[2] + f * turn)
            self._frames += 1
            depth = self._camera.render(pose)
            self._shadow.fuse(
                depth, self._camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), self._frames
            )
        self._before = (self._x, self._y, self._yaw)
        low, low_grid = project(self._shadow.low, self._band)
        planar = self._coverage.metrics(self._maps.low, self._maps.low_grid, None).coverage
        self.rows.append((self._path_length_m, planar, self._coverage.metrics(low, low_grid, None).coverage))


def fly(plan: str, runs: int, frames_per_step: int) -> list[np.ndarray]:
    """Rows (path m, planar observed coverage, camera observed coverage) per step, one array per run."""
    raster = load_buildings(plan)[0]
    specs = bench.plan_specs([raster], ["drl+pred"], runs, 0, predictor="models/predictor", policy="models/policy")
    predictor, policy = bench.load_predictor("models/predictor"), bench.load_policy("models/policy")
    envs: list[ShadowCameraEnv] = []

    def make_env(*args, **kwargs) -> ShadowCameraEnv:
        envs.append(ShadowCameraEnv(*args, **kwargs))
        envs[-1].frames_per_step = frames_per_step
        return envs[-1]

    bench.ExplorationEnv = make_env  # run_episode builds its env by this name
    for spec in tqdm(specs, desc=f"{plan} runs"):
        bench.run_episode(raster, spec, predictor, policy)
    return [np.asarray(env.rows) for env in envs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="C")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--frames-per-step", type=int, default=1)
    args = parser.parse_args()
    runs = fly(args.plan, args.runs, args.frames_per_step)
    print(
        f"{args.plan}, drl+pred, {args.runs} runs, {args.frames_per_step} camera frame(s) a step: "
        "observed coverage at a path (mean over runs that flew that far)"
    )
    print("path (m) | planar (the run's map) | camera, same poses | camera − planar")
    for path_m in PATHS_M:
        values = [r[np.searchsorted(r[:, 0], path_m, side="right") - 1, 1:] for r in runs if r[-1, 0] >= path_m]
        if values:
            planar, seen = np.mean(values, axis=0)
            print(f"{path_m:>8.0f} | {planar:.3f} | {seen:.3f} | {seen - planar:+.3f} ({len(values)} runs)")


if __name__ == "__main__":
    main()
