"""Predictor sample shards: samples recorded on the two-room plan (the ``shard_dir`` fixture) written and read back."""

import numpy as np

from edge_explorer.learn.predictor_shards import load_shards, shard_paths
from edge_explorer.world.grid import OCCUPIED


def test_shard_round_trip(shard_dir, scene):
    store = load_shards(shard_paths(shard_dir / "train"))
    assert 2 <= len(store) <= 8 and store.plan_names == [scene.name]
    np.testing.assert_array_equal(store.truth[0], scene.truth_low)
    assert np.all(np.diff(store.coverage) > 0) and store.coverage[-1] > 0.5
    for observed, cell in zip(store.observed, store.robot_cells, strict=True):
        assert observed.shape == scene.truth_low.shape
        assert observed[cell[0], cell[1]] != OCCUPIED  # the robot stands in a free cell
    np.testing.assert_allclose(store.observed_area_m2, [np.count_nonzero(o) * 0.04 for o in store.observed], rtol=1e-6)
