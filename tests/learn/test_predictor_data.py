"""Predictor samples: flights, explorers, shards, symmetries and the torch dataset."""

import numpy as np
import pytest

from edge_explorer.learn.predictor_data import (
    FlightLimits,
    LossWeighting,
    PlannerExplorer,
    PredictorDataset,
    RandomGoalWalk,
    dihedral,
    fly,
    load_shards,
    shard_paths,
)
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN


def test_random_goal_walk_covers_the_two_rooms_inside_the_configuration_space(scene):
    steps = list(fly(scene, RandomGoalWalk(), np.random.default_rng(0), limits=FlightLimits(max_steps=300)))
    coverage = np.array([s.coverage for s in steps])
    assert np.all(np.diff(coverage) >= 0) and coverage[0] > 0
    assert coverage[-1] > 0.9  # it leaves the first room through the door
    rows, cols = scene.grid.cell_of(*np.array([s.pose[:2] for s in steps]).T)
    assert not scene.blocked[rows, cols].any()


def test_flights_are_reproducible(scene):
    def poses(seed):
        return [s.pose for s in fly(scene, RandomGoalWalk(), np.random.default_rng(seed), limits=FlightLimits(40))]

    assert poses(3) == poses(3) and poses(3) != poses(4)


def test_a_planner_flies_as_an_explorer(scene):
    steps = list(fly(scene, PlannerExplorer("frontier"), np.random.default_rng(0), limits=FlightLimits(max_steps=8)))
    assert len(steps) == 8 and steps[-1].coverage >= steps[0].coverage


def test_shard_round_trip(shard_dir, scene):
    store = load_shards(shard_paths(shard_dir / "train"))
    assert 2 <= len(store) <= 8 and store.plan_names == [scene.name]
    np.testing.assert_array_equal(store.truth[0], scene.truth_low)
    assert np.all(np.diff(store.coverage) > 0) and store.coverage[-1] > 0.5
    for observed, cell in zip(store.observed, store.robot_cells, strict=True):
        assert observed.shape == scene.truth_low.shape
        assert observed[cell[0], cell[1]] != OCCUPIED  # the robot stands in a free cell
    np.testing.assert_allclose(store.observed_area_m2, [np.count_nonzero(o) * 0.04 for o in store.observed], rtol=1e-6)


@pytest.mark.parametrize("k", range(8))
def test_dihedral_moves_the_cell_with_the_map(k):
    codes = np.arange(12, dtype=np.int8).reshape(3, 4)
    out, (row, col) = dihedral(codes, (0, 1), k)
    assert out[row, col] == codes[0, 1]
    assert sorted(out.ravel()) == sorted(codes.ravel())


def test_the_eight_symmetries_differ():
    codes = np.arange(12, dtype=np.int8).reshape(3, 4)
    assert (
        len({dihedral(codes, (0, 0), k)[0].tobytes() + bytes(dihedral(codes, (0, 0), k)[0].shape) for k in range(8)})
        == 8
    )


def test_dataset_items_are_ego_centred_and_augmented_reproducibly(shard_dir):
    store = load_shards(shard_paths(shard_dir / "train"))
    plain = PredictorDataset(store, LossWeighting(0.1, 0.0), size_cells=64)
    x, target, weight = plain[0]
    assert x.shape == (2, 64, 64) and target.shape == weight.shape == (1, 64, 64)
    observed, truth = plain.windows(0)
    assert observed[32, 32] != OCCUPIED and truth[32, 32] == FREE  # the robot's cell is the centre
    assert float(weight[0][observed != UNKNOWN].max()) == 0.0  # observed cells do not count
    assert np.all(target[0].numpy()[truth == UNKNOWN] == 1)  # the exterior is "occupied"
    augmented = PredictorDataset(store, augment=True, seed=7, size_cells=64)
    first = [augmented[i][0] for i in range(len(store))]
    assert all(bool((a == b).all()) for a, b in zip(first, [augmented[i][0] for i in range(len(store))], strict=True))
    assert any(not bool((a == plain[i][0]).all()) for i, a in enumerate(first))
    assert all(float(a.sum()) == float(plain[i][0].sum()) for i, a in enumerate(first))  # same cells, moved
