"""Fixtures of the learn tests: the two-room plan as a flight scene, and a tiny sample shard made from it."""

import numpy as np
import pytest

from edge_explorer.learn.predictor_data import SampleConfig, collect_plan_samples
from edge_explorer.learn.predictor_flights import FlightLimits, RandomGoalWalk, Scene
from edge_explorer.learn.predictor_shards import write_shard
from edge_explorer.world.catalog import plan_to_raster
from tests.conftest import two_room_plan


@pytest.fixture(scope="session")
def scene() -> Scene:
    return Scene.from_raster(plan_to_raster(two_room_plan()))


@pytest.fixture(scope="session")
def shard_dir(tmp_path_factory, scene):
    """train/ and val/ folders, each one finished shard of 8 samples of the two-room plan."""
    root = tmp_path_factory.mktemp("samples")
    config = SampleConfig(samples_per_plan=8, limits=FlightLimits(max_steps=300))
    for split, seed in (("train", 0), ("val", 1)):
        samples = collect_plan_samples(scene, [RandomGoalWalk()], np.random.default_rng(seed), config)
        (root / split).mkdir()
        write_shard(root / split / "shard-00000.npz", [scene], [samples])
        (root / split / "shard-00000.json").write_text("{}")
    return root
