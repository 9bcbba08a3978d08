"""Two-level observed maps: 0.05 m and 0.20 m trinary codes built from the same observations (docs/design.md §5).

The high-res map holds what the sensor saw, cell by cell. The low-res map is always derived from it by
:func:`coarsen_codes` — a low cell is OCCUPIED if any high cell of its block is OCCUPIED, else FREE if any is
FREE, else UNKNOWN (the rule :meth:`~edge_explorer.world.raster.PlanRaster.coarsened` uses for the ground truth,
so a fully observed map matches the low-res truth). Each scan recomputes only the blocks it touched.

Update rule: OctoMap-style log-odds per high-res cell (:class:`~edge_explorer.mapping.voxels.FusionConfig`), with
the daemon's voxel fusion's hit 0.7, clamp 0.12 / 0.97 and threshold 0.5, and a miss of 0.3 (:data:`PLANAR_FUSION`).
A scan is a patch of codes (UNKNOWN where it saw nothing); each of its known cells adds one hit (OCCUPIED) or one miss
(FREE) to that cell's log-odds, and the cell's code is OCCUPIED at or above the threshold, FREE below it. A first
observation therefore decides the code on its own, while a cell seen free many times is no longer flipped by one
noisy hit — the map the simulator trains with accumulates evidence the way the map the daemon flies with does.

**The miss** is the planar sensor's own. That sensor labels each 8-neighbour of every return occupied with
probability 0.1 (docs/design.md §6), so the free cell in front of a wall is hit in some 20–30 % of the scans that see
the wall, while a ray that crossed a cell is never wrong. With OctoMap's miss of 0.4 (log-odds −0.41 against the
hit's +0.85) three misses were needed to undo one such hit, and at 95 % coverage the walls stood one 0.05 m cell
thick on the vehicle's side: 2–3 % of N_M at 0.20 m was observed OCCUPIED and free in truth, a floor under every
method's correct coverage. A miss of 0.3 (−0.85, the hit mirrored) needs two. 36 generated val plans, drl+pred,
1 run, seed 0, paired per plan against 0.4 (session 44): path to 95 % correct coverage × 0.73 ± 0.04 and reached
in 36 plans instead of 31, to 90 % correct × 0.97 ± 0.03, to 95 % coverage × 0.99 ± 0.03; 0.35 did the same on
plans 12–35.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from edge_explorer.mapping.voxels import UNKNOWN_LOGODDS, FusionConfig
from edge_explorer.world.grid import CELL_DTYPE, FREE, LOW_RES_M, OCCUPIED, UNKNOWN, GridSpec, resolution_factor

PLANAR_FUSION = FusionConfig(prob_miss=0.3)  # the planar sensor's log-odds update (module docstring)


@njit(cache=True)
def _coarsen_blocks(high, factor, low, lr0, lr1, lc0, lc1):
    """low[lr0:lr1, lc0:lc1] ← the coarse code of each factor×factor block of ``high`` (missing cells UNKNOWN)."""
    n_rows, n_cols = high.shape
    for bi in range(lr0, lr1):
        for bj in range(lc0, lc1):
            any_free = False
            any_occupied = False
            for i in range(bi * factor, min((bi + 1) * factor, n_rows)):
                for j in range(bj * factor, min((bj + 1) * factor, n_cols)):
                    v = high[i, j]
                    any_occupied |= v == OCCUPIED
                    any_free |= v == FREE
            low[bi, bj] = OCCUPIED if any_occupied else (FREE if any_free else UNKNOWN)


@njit(cache=True)
def _apply_patch(high, logodds, low, factor, patch, row0, col0, hit, miss, clamp_min, clamp_max, threshold):
    """One hit or miss per known patch cell into ``logodds``; ``high`` ← the resulting codes; recompute the low
    blocks that changed.

    Returns the (rows, cols) of the high-res cells whose code changed.
    """
    changed_rows = np.empty(patch.size, np.int64)
    changed_cols = np.empty(patch.size, np.int64)
    n = 0
    for i in range(patch.shape[0]):
        for j in range(patch.shape[1]):
            observed = patch[i, j]
            if observed == UNKNOWN:
                continue
            r, c = row0 + i, col0 + j
            value = 0 if logodds[r, c] == UNKNOWN_LOGODDS else np.int32(logodds[r, c])
            value += hit if observed == OCCUPIED else miss
            value = min(max(value, clamp_min), clamp_max)
            logodds[r, c] = value
            code = OCCUPIED if value >= threshold else FREE
            if code != high[r, c]:
                high[r, c] = code
                changed_rows[n] = r
                changed_cols[n] = c
                n += 1
    for k in range(n):
        bi = changed_rows[k] // factor
        bj = changed_cols[k] // factor
        _coarsen_blocks(high, factor, low, bi, bi + 1, bj, bj + 1)
    return changed_rows[:n], changed_cols[:n]


def coarsen_codes(high_codes: np.ndarray, factor: int) -> np.ndarray:
    """Trinary codes on ``factor``× coarser cells: OCCUPIED if any OCCUPIED, else FREE if any FREE, else UNKNOWN.

    Blocks start at index 0; where the shape does not divide, the missing cells count as UNKNOWN (the coarse shape
    is rounded up, like :meth:`GridSpec.coarsened`).
    """
    if factor < 1:
        raise ValueError(f"coarsening factor must be ≥ 1, got {factor}")
    rows, cols = -(-high_codes.shape[0] // factor), -(-high_codes.shape[1] // factor)
    low = np.empty((rows, cols), dtype=CELL_DTYPE)
    _coarsen_blocks(np.ascontiguousarray(high_codes, dtype=CELL_DTYPE), factor, low, 0, rows, 0, cols)
    return low


@dataclass
class ObservedMaps:
    """The observed high- and low-res maps of one flight; mutable, updated scan by scan."""

    high_grid: GridSpec
    low_grid: GridSpec
    high: np.ndarray  # int8 codes on high_grid
    low: np.ndarray  # int8 codes on low_grid, always coarsen_codes(high, factor)
    fusion: FusionConfig = PLANAR_FUSION  # the log-odds update (its range settings are not used here)
    # int16 per high cell, UNKNOWN_LOGODDS where unobserved; made on the first patch (maps built from codes and
    # only read, as the daemon's per-decision projection, never need it)
    logodds: np.ndarray | None = field(default=None, init=False, repr=False)

    @classmethod
    def empty(cls, high_grid: GridSpec, low_resolution_m: float = LOW_RES_M) -> ObservedMaps:
        """All-UNKNOWN maps; the low grid shares the high grid's origin."""
        low_grid = high_grid.coarsened(resolution_factor(high_grid.resolution_m, low_resolution_m))
        return cls(
            high_grid,
            low_grid,
            np.zeros(high_grid.shape, dtype=CELL_DTYPE),
            np.zeros(low_grid.shape, dtype=CELL_DTYPE),
        )

    def __post_init__(self) -> None:
        self._factor = resolution_factor(self.high_grid.resolution_m, self.low_grid.resolution_m)
        if self.high.shape != self.high_grid.shape or self.low.shape != self.low_grid.shape:
            raise ValueError("map arrays must have their grids' shapes")
        self._update = self.fusion.scaled_logodds()

    @property
    def factor(self) -> int:
        """How many high-res cells make one low-res cell along each axis (4 for 0.05 m / 0.20 m)."""
        return self._factor

    def apply_patch(self, row0: int, col0: int, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Write a scan patch whose cell (0, 0) is high-res cell (row0, col0).

        The patch (int8 codes) must lie on the map. Its UNKNOWN cells leave the map unchanged; each known cell is
        one hit or miss for that cell (module docstring), and the low-res blocks that changed are recomputed.
        Returns the (rows, cols) index arrays of the high-res cells whose code changed (for incremental consumers
        such as :class:`~edge_explorer.mapping.ego.InflatedMap`).
        """
        rows, cols = self.high.shape
        if row0 < 0 or col0 < 0 or row0 + codes.shape[0] > rows or col0 + codes.shape[1] > cols:
            raise ValueError(f"patch at ({row0}, {col0}) of shape {codes.shape} leaves the map {self.high.shape}")
        patch = np.ascontiguousarray(codes, dtype=CELL_DTYPE)
        if self.logodds is None:  # maps that start from codes carry one observation's worth of evidence per cell
            hit, miss = self._update[0], self._update[1]
            evidence = np.where(self.high == OCCUPIED, hit, np.where(self.high == FREE, miss, UNKNOWN_LOGODDS))
            self.logodds = evidence.astype(np.int16)
        return _apply_patch(self.high, self.logodds, self.low, self._factor, patch, row0, col0, *self._update)

    def observed_area_m2(self) -> float:
        """Area of the known cells of the low-res map (the input of dynamic thresholding)."""
        return float(np.count_nonzero(self.low)) * self.low_grid.resolution_m**2
