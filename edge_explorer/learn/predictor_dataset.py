"""The map predictor's torch dataset: recorded samples turned into network tensors, with symmetry augmentation.

:class:`PredictorDataset` turns a sample of a :class:`~edge_explorer.learn.predictor_shards.SampleStore` into network
tensors: a random symmetry of the plan (the 8 flips and 90° rotations — an axis-aligned building stays a valid
building) applied in the map frame, then the ego shift :func:`~edge_explorer.mapping.ego.pad_shift` (robot at
(128, 128)) and the encoding of :mod:`edge_explorer.predict.encoding`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from edge_explorer.learn.predictor_shards import SampleStore
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS, pad_shift
from edge_explorer.predict.encoding import encode_windows, loss_weights, occupancy_target


def dihedral(codes: np.ndarray, cell: tuple[int, int], k: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Symmetry ``k`` ∈ 0..7 of the square's group applied to a map and a cell on it: transpose if k ≥ 4, then
    flip rows if k & 1, flip columns if k & 2. k = 0 is the identity."""
    row, col = cell
    if k & 4:
        codes, row, col = codes.T, col, row
    if k & 1:
        codes, row = codes[::-1], codes.shape[0] - 1 - row
    if k & 2:
        codes, col = codes[:, ::-1], codes.shape[1] - 1 - col
    return codes, (row, col)


@dataclass(frozen=True)
class LossWeighting:
    """Per-cell BCE weights (:func:`edge_explorer.predict.encoding.loss_weights`)."""

    exterior_weight: float = 0.1
    observed_weight: float = 0.0
    wall_weight: float = 1.0


class PredictorDataset(torch.utils.data.Dataset):
    """(input 2×256×256, target 1×256×256, weight 1×256×256) float32 tensors of a :class:`SampleStore`.

    With ``augment``, sample ``i`` in epoch ``e`` takes the symmetry drawn from ``(seed, e, i)``, so a run is
    reproducible and a resumed run sees the same data; without it every sample is used as recorded.
    """

    def __init__(
        self,
        store: SampleStore,
        weighting: LossWeighting = LossWeighting(),
        augment: bool = False,
        seed: int = 0,
        size_cells: int = PREDICTOR_WINDOW_CELLS,
    ) -> None:
        self.store = store
        self.weighting = weighting
        self.augment = augment
        self.seed = seed
        self.size_cells = size_cells
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.store)

    def windows(self, index: int, symmetry: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(observed, truth) int8 ego windows of a sample under a symmetry."""
        store = self.store
        cell = (int(store.robot_cells[index, 0]), int(store.robot_cells[index, 1]))
        observed, ego_cell = dihedral(store.observed[index], cell, symmetry)
        truth, _ = dihedral(store.truth[store.sample_plan[index]], cell, symmetry)
        return pad_shift(observed, ego_cell, self.size_cells), pad_shift(truth, ego_cell, self.size_cells)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        symmetry = int(np.random.default_rng([self.seed, self.epoch, index]).integers(8)) if self.augment else 0
        observed, truth = self.windows(index, symmetry)
        w = self.weighting
        return (
            torch.from_numpy(encode_windows(observed)),
            torch.from_numpy(occupancy_target(truth)[None]),
            torch.from_numpy(loss_weights(truth, observed, w.exterior_weight, w.observed_weight, w.wall_weight)[None]),
        )
