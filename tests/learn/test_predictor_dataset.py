"""The predictor's torch dataset: symmetries, ego centring and reproducible augmentation."""

import numpy as np
import pytest

from edge_explorer.learn.predictor_dataset import LossWeighting, PredictorDataset, dihedral
from edge_explorer.learn.predictor_shards import load_shards, shard_paths
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN


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
