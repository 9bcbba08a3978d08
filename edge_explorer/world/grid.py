"""Grids and cell codes shared by every stage (docs/design.md §3).

A grid is ``GridSpec(origin_xy, resolution_m, shape)``: cell (row i, col j) covers
x ∈ [x0 + j·r, x0 + (j+1)·r), y ∈ [y0 + i·r, y0 + (i+1)·r). Rows grow with y.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Trinary cell codes (int8), the paper's values. NON_FLIGHT only appears in policy observations:
# the inflation band around occupied cells that the vehicle must not enter.
FREE: int = -1
UNKNOWN: int = 0
OCCUPIED: int = 1
NON_FLIGHT: int = 2
CELL_DTYPE = np.int8

HIGH_RES_M: float = 0.05
LOW_RES_M: float = 0.20


@dataclass(frozen=True)
class GridSpec:
    """Placement of a 2-D raster in the ``map`` frame."""

    origin_xy: tuple[float, float]
    resolution_m: float
    shape: tuple[int, int]  # (rows along y, cols along x)

    def __post_init__(self) -> None:
        if not (self.resolution_m > 0 and np.isfinite(self.resolution_m)):
            raise ValueError(f"GridSpec resolution_m must be a positive number, got {self.resolution_m!r}")
        if len(self.shape) != 2 or min(self.shape) <= 0:
            raise ValueError(f"GridSpec shape must be two positive ints, got {self.shape!r}")

    @property
    def size_xy_m(self) -> tuple[float, float]:
        return (self.shape[1] * self.resolution_m, self.shape[0] * self.resolution_m)

    def cell_of(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) integer indices of the cells containing the points (may be out of bounds)."""
        x0, y0 = self.origin_xy
        col = np.floor((np.asarray(x_m) - x0) / self.resolution_m).astype(np.int64)
        row = np.floor((np.asarray(y_m) - y0) / self.resolution_m).astype(np.int64)
        return row, col

    def center_of(self, row: np.ndarray | int, col: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) in metres of the centres of cells (row, col)."""
        x0, y0 = self.origin_xy
        r = self.resolution_m
        return x0 + (np.asarray(col) + 0.5) * r, y0 + (np.asarray(row) + 0.5) * r

    def contains(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])

    def coarsened(self, factor: int) -> GridSpec:
        """The grid with ``factor``× larger cells over the same origin (shape rounded up)."""
        if factor < 1:
            raise ValueError(f"coarsening factor must be ≥ 1, got {factor}")
        rows = -(-self.shape[0] // factor)
        cols = -(-self.shape[1] // factor)
        return GridSpec(self.origin_xy, self.resolution_m * factor, (rows, cols))


def resolution_factor(fine_m: float, coarse_m: float) -> int:
    """Integer ratio coarse/fine, raising if the two resolutions do not nest."""
    factor = int(round(coarse_m / fine_m))
    if factor < 1 or abs(factor * fine_m - coarse_m) > 1e-6:
        raise ValueError(f"resolution {coarse_m} m is not an integer multiple of {fine_m} m")
    return factor
