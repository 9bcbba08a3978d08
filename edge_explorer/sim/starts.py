"""Where a simulated run starts: the exploration benchmark's start pose of a building, which the daemon's simulated
flights, the learned policy's evaluation and the profiler's flights share (:func:`start_pose`)."""

from __future__ import annotations

from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.raster import PlanRaster, clearance_m
from edge_explorer.world.seeds import derived_seed

START_CLEARANCE_M = 0.5  # from the start pose to the nearest wall
_START_ATTEMPTS = 100


def start_pose(raster: PlanRaster, seed: int) -> tuple[float, float, float]:
    """The start pose of every run on ``raster``: the simulator's uniform draw from its configuration space, seeded
    from the benchmark seed and the building's name (so it does not depend on which other plans are benchmarked),
    redrawn until it lies at least :data:`START_CLEARANCE_M` from the walls — a vehicle takes off in the open, and
    one drawn at the very edge of the configuration space would touch a wall with its first, noisy, hover."""
    env = ExplorationEnv([raster], EnvConfig(motion_noise=False))
    clearance = clearance_m(raster)
    best, best_clearance = None, -1.0
    for attempt in range(_START_ATTEMPTS):
        env.reset(seed=derived_seed(seed, raster.name, 0, attempt))
        row, col = (int(v) for v in raster.grid.cell_of(*env.pose[:2]))
        if clearance[row, col] > best_clearance:
            best, best_clearance = env.pose, float(clearance[row, col])
        if best_clearance >= START_CLEARANCE_M:
            break
    assert best is not None
    return best
