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
from edge_explorer.plan.goal_policy import GoalPolicyPlanner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.runtime.daemon.report import CoverageTruth
from edge_explorer.sim.camera import CameraPose, DepthCamera
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import load_buildings

PATHS_M = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)


def fly(plan: str, runs: int, frames_per_step: int) -> list[np.ndarray]:
    """Rows (path m, planar observed coverage, camera observed coverage) per step, one array per run."""
    raster = load_buildings(plan)[0]
    specs = bench.plan_specs([raster], ["drl+pred"], runs, 0, predictor="models/predictor", policy="models/policy")
    predictor, policy = bench.load_predictor("models/predictor"), bench.load_policy("models/policy")
    band, camera, truth = HeightBand(), DepthCamera(raster), CoverageTruth(raster)
    region = VoxelRegion.covering(raster.grid, *band_z_range_m(band))
    out = []
    for spec in tqdm(specs, desc=f"{plan} runs"):
        config = EnvConfig(coverage_goal=1.0, max_steps=spec.max_steps, thresholds=thresholds_of(predictor))
        env = ExplorationEnv([raster], config, predictor=predictor)
        planner = GoalPolicyPlanner(policy, table=env.table)
        planner.reset()
        _, info = env.reset(seed=spec.seed, options={"start_pose": spec.start_pose})
        shadow = VoxelMaps(region, FusionConfig())
        rows, previous, before, frames = [], 0, env.pose, 0
        while len(rows) <= spec.max_steps:
            after = env.pose
            turn = (after[2] - before[2] + np.pi) % (2 * np.pi) - np.pi
            for k in range(1, frames_per_step + 1):  # the last frame at the step's end pose, the others on the way
                f = k / frames_per_step
                x_m, y_m = before[0] + f * (after[0] - before[0]), before[1] + f * (after[1] - before[1])
                pose = CameraPose(x_m, y_m, band.flight_z_m, before[2] + f * turn)
                depth = camera.render(pose)
                frames += 1
                shadow.fuse(depth, camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), frames)
            before = after
            low, low_grid = project(shadow.low, band)
            planar = truth.metrics(env.maps.low, env.maps.low_grid, None).coverage
            rows.append((info["path_length_m"], planar, truth.metrics(low, low_grid, None).coverage))
            if info["coverage"] >= spec.coverage_goal and info["correct_coverage"] >= spec.coverage_goal:
                break
            action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
            if action is None:
                break
            _, _, _, _, info = env.step(action)
            previous = 0 if info["collided"] else action
        out.append(np.asarray(rows))
    return out


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
