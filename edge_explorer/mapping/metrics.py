"""Exploration metrics, exactly as docs/design.md §7 defines them; every report uses these names.

All counts are over the building's interior cells at 0.20 m (walls inside the outline included):

* ``N_M``: number of interior cells;
* ``T``: interior cells whose *known* state equals the ground truth; ``TP``: those of them that are occupied;
* ``F1 = TP / (TP + 0.5·(N_M − T))``;
* coverage: interior cells whose state is known / N_M; correct coverage: T / N_M.

The known state of a cell is what the sensor observed; for methods with a predictor, cells never observed take the
thresholded prediction (observed cells always win, :func:`known_codes`). Without a prediction layer, TP counts the
observed occupied cells and N_M − T the interior cells not (correctly) observed — the paper's phase-1 reward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from edge_explorer.world.grid import OCCUPIED, UNKNOWN


@dataclass(frozen=True)
class MapMetrics:
    """Counts of one map against the truth and the ratios built from them."""

    n_m: int  # interior cells
    t: int  # interior cells whose known state equals the truth
    tp: int  # … of which occupied
    known: int  # interior cells whose state is known (right or wrong)

    @property
    def f1(self) -> float:
        """TP / (TP + 0.5·(N_M − T)); 1.0 for a perfect map even if it has no occupied cell."""
        denominator = self.tp + 0.5 * (self.n_m - self.t)
        return self.tp / denominator if denominator > 0 else 1.0

    @property
    def coverage(self) -> float:
        return self.known / self.n_m

    @property
    def correct_coverage(self) -> float:
        return self.t / self.n_m


def known_codes(observed: np.ndarray, thresholded: np.ndarray | None = None) -> np.ndarray:
    """The map a method knows: observed codes, with the thresholded prediction where nothing was observed."""
    if thresholded is None:
        return observed
    if thresholded.shape != observed.shape:
        raise ValueError(f"thresholded prediction {thresholded.shape} and observed map {observed.shape} differ")
    return np.where(observed != UNKNOWN, observed, thresholded)


def map_metrics(
    observed_low: np.ndarray,
    truth_low: np.ndarray,
    interior_low: np.ndarray,
    thresholded_low: np.ndarray | None = None,
) -> MapMetrics:
    """N_M, T, TP and known cells of the low-res observed map (plus an optional thresholded prediction).

    ``truth_low`` holds OCCUPIED/FREE codes, ``interior_low`` the building's interior (bool); all arrays share the
    low-res grid. Raises ``ValueError`` if the shapes differ or the interior is empty.
    """
    if not (observed_low.shape == truth_low.shape == interior_low.shape):
        raise ValueError(
            f"shapes differ: observed {observed_low.shape}, truth {truth_low.shape}, interior {interior_low.shape}"
        )
    if thresholded_low is None:
        thresholded_low = observed_low
    elif thresholded_low.shape != observed_low.shape:
        raise ValueError(f"thresholded prediction {thresholded_low.shape} and observed map {observed_low.shape} differ")
    n_m, t, tp, known = _count(observed_low, thresholded_low, truth_low, interior_low)
    if n_m == 0:
        raise ValueError("the interior mask is empty: N_M = 0")
    return MapMetrics(n_m=n_m, t=t, tp=tp, known=known)


@njit(cache=True)
def _count(observed, thresholded, truth, interior):
    """(N_M, T, TP, known) in one pass; the known state is observed, else thresholded."""
    n_m = t = tp = known = 0
    for i in range(observed.shape[0]):
        for j in range(observed.shape[1]):
            if not interior[i, j]:
                continue
            n_m += 1
            state = observed[i, j] if observed[i, j] != UNKNOWN else thresholded[i, j]
            if state != UNKNOWN:
                known += 1
                if state == truth[i, j]:
                    t += 1
                    if state == OCCUPIED:
                        tp += 1
    return n_m, t, tp, known


def path_length_m(positions_xy_m: np.ndarray) -> float:
    """Sum of the distances between consecutive positions ((N, 2) metres)."""
    xy = np.asarray(positions_xy_m, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"positions must have shape (N, 2), got {xy.shape}")
    if len(xy) < 2:
        return 0.0
    return float(np.hypot(*np.diff(xy, axis=0).T).sum())
