"""Projection of a 3-D voxel map to the 2-D trinary map the simulator, predictor and planner use.

Only a horizontal band of the voxel map counts (docs/design.md §5): voxels whose centre lies below ``min_z_m`` (1.5 m,
the height below which furniture is "low" and not part of the 2-D plan) are ignored, and so is the ceiling band
from ``max_z_m`` (2.5 m) up. The flight height, 1.7 m, lies inside the band. Column rule, per (row, col):

* OCCUPIED if any voxel of the band is occupied (an obstacle the vehicle at flight height could touch);
* else FREE if every band voxel below the flight height (layers from 1.5 m up to 1.7 m) is known free — not
  merely some voxel: a camera at 1.7 m sees over a cabinet taller than itself, and the free voxels above its
  top must not turn the cabinet's unseen inside into free floor;
* else UNKNOWN.

The result is an int8 code array on the voxel map's :class:`GridSpec` (same origin and resolution as its
columns). Place the voxel region on a plan grid's origin and :func:`align_to_grid` crops or pads it onto any
grid that nests with it, e.g. the grids of ``PlanRaster.truth_codes()`` and of ``PlanRaster.coarsened(0.20)``;
:func:`onto_grid` also takes codes onto a grid that does not nest (nearest cell centre).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from edge_explorer.mapping.voxels import UNKNOWN_LOGODDS, VoxelGrid
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.plan import TALL_HEIGHT_M


@dataclass(frozen=True)
class HeightBand:
    """Voxels with centre z in [min_z_m, max_z_m) are projected; keep ``max_z_m`` below the lowest ceiling.

    ``flight_z_m`` is the vehicle's flight height: a column is FREE only if every band layer below it is seen.
    """

    min_z_m: float = TALL_HEIGHT_M
    max_z_m: float = 2.5
    flight_z_m: float = 1.7

    def __post_init__(self) -> None:
        if not self.min_z_m < self.flight_z_m < self.max_z_m:
            raise ValueError(
                f"height band needs min_z_m < flight_z_m < max_z_m, got {self.min_z_m}, {self.flight_z_m}, "
                f"{self.max_z_m}"
            )

    def layers(self, layer_centers_m: np.ndarray) -> np.ndarray:
        """Indices of the layers in the band."""
        return np.nonzero((layer_centers_m >= self.min_z_m) & (layer_centers_m < self.max_z_m))[0]


def project(voxels: VoxelGrid, band: HeightBand = HeightBand()) -> tuple[np.ndarray, GridSpec]:
    """(int8 codes [row y, col x], their grid) of ``voxels`` under the column rule of the module docstring.

    The same rule as :func:`project_states`, column by column in one compiled pass over the band's layers (no
    per-voxel temporaries: the daemon projects its 0.05 m map at every decision).
    """
    codes = np.empty(voxels.shape[:2], dtype=CELL_DTYPE)
    project_box(voxels, band, codes, (0, codes.shape[0]), (0, codes.shape[1]))
    return codes, voxels.grid


def project_box(
    voxels: VoxelGrid, band: HeightBand, codes: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]
) -> None:
    """Bring ``codes`` (the shape of ``voxels``' columns) up to date over rows [rows[0], rows[1]) × columns
    [cols[0], cols[1]) (clipped to the array), as :func:`project` gives them; the other cells are left as they are.
    A map that knows where its voxels changed since its last projection reprojects only there
    (:meth:`edge_explorer.mapping.growing.GrowingMaps.project`)."""
    if codes.shape != voxels.shape[:2]:
        raise ValueError(f"codes of shape {codes.shape} do not hold the columns of a {voxels.shape} voxel map")
    z = voxels.layer_centers_m()
    layers = band.layers(z)
    # The layers below flight height are a prefix of the band's: layer centres ascend.
    below_flight = int(np.count_nonzero((z[layers] - voxels.resolution_m / 2) < band.flight_z_m))
    first = int(layers[0]) if len(layers) else 0
    r0, r1 = max(int(rows[0]), 0), min(int(rows[1]), codes.shape[0])
    c0, c1 = max(int(cols[0]), 0), min(int(cols[1]), codes.shape[1])
    _project_kernel(
        voxels.log_odds,
        first,
        len(layers),
        below_flight,
        voxels.threshold_logodds,
        UNKNOWN_LOGODDS,
        codes,
        r0,
        r1,
        c0,
        c1,
    )


# The kernel finds unseen voxels by a column's minimum: unknown must be the smallest log-odds value there is.
assert UNKNOWN_LOGODDS == np.iinfo(np.int16).min
_INT16_MAX = np.iinfo(np.int16).max


@numba.njit(cache=True, nogil=True)
def _project_kernel(log_odds, first, count, below_flight, threshold, unknown, codes, r0, r1, c0, c1):
    """codes[i, j] ← the column rule over layers first … first + count − 1 of log_odds[i, j] (contiguous, as
    :meth:`HeightBand.layers` returns them), the first ``below_flight`` of them below flight height, for rows
    [r0, r1) and columns [c0, c1).

    Two reductions per column instead of a branch per voxel: some band voxel is occupied iff the band's maximum is
    ≥ ``threshold`` and not ``unknown`` (which is the int16 minimum), and some layer below flight height is unseen
    iff their minimum is ``unknown`` (a minimum over no layer never is). The compiler vectorises both (SIMD max and
    min over the column's contiguous layers); the branch per voxel this replaced (whether a voxel is unknown, free
    or occupied is unpredictable) took 2–3 times as long on the daemon's 0.05 m map.
    tests/mapping/test_projection_reference.py keeps it and checks that both give the same codes.
    """
    for i in range(r0, r1):
        for j in range(c0, c1):
            column = log_odds[i, j, first : first + count]
            highest = np.int16(unknown)
            for k in range(count):
                highest = max(highest, column[k])
            lowest = np.int16(_INT16_MAX)
            for k in range(below_flight):
                lowest = min(lowest, column[k])
            if highest >= threshold and highest != unknown:
                codes[i, j] = OCCUPIED
            elif lowest == unknown:
                codes[i, j] = UNKNOWN
            else:
                codes[i, j] = FREE


def project_states(states: np.ndarray, layer_bottoms_m: np.ndarray, band: HeightBand) -> np.ndarray:
    """The column rule on per-voxel codes of the band's layers (``states`` [row, col, layer], int8).

    Shared by :func:`project` and anything that can label voxels (the OctoMap comparison), so both are
    projected identically.
    """
    codes = np.full(states.shape[:2], UNKNOWN, dtype=CELL_DTYPE)
    below_flight = layer_bottoms_m < band.flight_z_m
    codes[(states[:, :, below_flight] != UNKNOWN).all(axis=2)] = FREE
    codes[(states == OCCUPIED).any(axis=2)] = OCCUPIED
    return codes


def align_to_grid(codes: np.ndarray, grid: GridSpec, target: GridSpec) -> np.ndarray:
    """``codes`` (on ``grid``) copied onto ``target``: same resolution, origins a whole number of cells apart.

    Target cells outside ``grid`` are UNKNOWN. Raises ``ValueError`` if the grids do not nest.
    """
    r = grid.resolution_m
    if abs(target.resolution_m - r) > 1e-9:
        raise ValueError(f"grids have different resolutions ({r} m vs {target.resolution_m} m)")
    offset = [(t - g) / r for t, g in zip(target.origin_xy, grid.origin_xy, strict=True)]
    dcol, drow = (int(round(v)) for v in offset)
    if max(abs(dcol - offset[0]), abs(drow - offset[1])) > 1e-6:
        raise ValueError(f"grid origins {grid.origin_xy} and {target.origin_xy} are not whole cells apart")
    out = np.full(target.shape, UNKNOWN, dtype=CELL_DTYPE)
    rows, cols = target.shape
    r0, c0 = max(0, -drow), max(0, -dcol)  # first target row/col that has a source
    r1 = min(rows, grid.shape[0] - drow)
    c1 = min(cols, grid.shape[1] - dcol)
    if r1 > r0 and c1 > c0:
        out[r0:r1, c0:c1] = codes[r0 + drow : r1 + drow, c0 + dcol : c1 + dcol]
    return out


def onto_grid(codes: np.ndarray, grid: GridSpec, target: GridSpec) -> np.ndarray:
    """``codes`` (on ``grid``) on ``target``: :func:`align_to_grid` when the grids nest, else each target cell takes
    the code of the ``grid`` cell holding its centre (UNKNOWN outside ``grid``). A map that grows from take-off
    nests with a plan grid when both origins lie on the 0.20 m lattice; this covers the others."""
    try:
        return align_to_grid(codes, grid, target)
    except ValueError:
        pass
    rows, cols = np.indices(target.shape)
    x, y = target.center_of(rows, cols)
    src_rows, src_cols = grid.cell_of(x, y)
    inside = grid.contains(src_rows, src_cols)
    out = np.full(target.shape, UNKNOWN, dtype=CELL_DTYPE)
    out[inside] = codes[src_rows[inside], src_cols[inside]]
    return out
