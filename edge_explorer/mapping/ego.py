"""Ego-centric map transforms and the policy observation: the one implementation every stage shares.

The simulator, the trainer, the benchmark and the on-device daemon all build the predictor input and the policy
observation with these functions, so the networks see in flight exactly what they saw in training
(docs/design.md §2, §5). Everything here is a pure function on numpy arrays of int8 cell codes
(:data:`~edge_explorer.world.grid.FREE`, ``UNKNOWN``, ``OCCUPIED``, ``NON_FLIGHT``) indexed ``[row (y), col (x)]``,
except :class:`InflatedMap`, the incremental form of inflation that the simulator keeps from step to step.

Two ego frames:

* **North-up window** (:func:`pad_shift`, inverse :func:`unshift`): the predictor input. The low-res map is
  padded with UNKNOWN and shifted so the robot's cell sits at index ``(size // 2, size // 2)`` — (128, 128) in the
  default 256×256 window at 0.20 m (51.2 m, more than any 21 m × 11 m building seen from any point inside it).
  No rotation, so the inverse is exact.
* **Heading-up window** (:func:`rotate_crop`): the policy observation. The map is rotated about the centre of the
  robot's cell so that the robot's heading points along **+row** (increasing row index, the direction north has
  in an un-rotated map array) and the robot's right along +col; the robot's cell is the centre
  ``(size // 2, size // 2)`` — (118, 118) of 237×237. Drawn with ``imshow(origin="lower")`` like the maps
  themselves, the heading points **up** and the robot's left is on the left. It is a proper rotation (no
  mirror): at yaw = +90° (facing north, +y) the heading-up window equals the north-up one.

Inflation (:func:`inflate_codes`, incrementally :class:`InflatedMap`) turns every non-occupied cell within
``radius_m`` (default the robot radius, 0.25 m) of an occupied cell into NON_FLIGHT: a binary dilation by the
disk :func:`inflation_kernel` (identical to ``cv2.dilate`` with that kernel, which the tests check; done in numba
because stamping the disk around the few occupied cells is several times faster than ``cv2.dilate`` with a
non-rectangular kernel, and it can be updated cell by cell). The observation is
``rotate_crop(inflate_codes(map))``: inflation happens in the map frame, so it does not depend on the heading.

Rotations use ``cv2.warpAffine`` with nearest-neighbour sampling; opencv has no int8 warp, so the codes' bytes
are warped as uint8 (UNKNOWN = 0 is the border value) and viewed back as int8.
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np
from numba import njit

from edge_explorer.world.grid import CELL_DTYPE, NON_FLIGHT, OCCUPIED, UNKNOWN
from edge_explorer.world.raster import ROBOT_RADIUS_M

PREDICTOR_WINDOW_CELLS = 256  # north-up predictor input at 0.20 m
OBSERVATION_WINDOW_CELLS = 237  # heading-up policy observation (0.05 m high layer, 0.20 m thresholded layer)
INFLATION_RADIUS_M = ROBOT_RADIUS_M
NUM_ACTIONS = 6  # length of the one-hot last action; equals len(edge_explorer.vehicle.dynamics.Action)

Cell = tuple[int, int]  # (row, col) on a grid


# ---- north-up pad + shift (predictor input) -----------------------------------------------------------------------
def _window_overlap(robot_cell: Cell, size_cells: int, map_shape: tuple[int, int]) -> tuple[slice, slice, slice, slice]:
    """Slices (map rows, map cols, window rows, window cols) of the part of the window that lies on the map."""
    half = size_cells // 2
    row0, col0 = robot_cell[0] - half, robot_cell[1] - half
    r_lo, r_hi = max(row0, 0), min(row0 + size_cells, map_shape[0])
    c_lo, c_hi = max(col0, 0), min(col0 + size_cells, map_shape[1])
    if r_lo >= r_hi or c_lo >= c_hi:
        empty = slice(0, 0)
        return empty, empty, empty, empty
    return (
        slice(r_lo, r_hi),
        slice(c_lo, c_hi),
        slice(r_lo - row0, r_hi - row0),
        slice(c_lo - col0, c_hi - col0),
    )


def pad_shift(
    codes: np.ndarray, robot_cell: Cell, size_cells: int = PREDICTOR_WINDOW_CELLS, fill: int = UNKNOWN
) -> np.ndarray:
    """North-up ``size_cells``² window of ``codes`` with ``robot_cell`` at ``(size // 2, size // 2)``.

    Cells of the window outside the map are ``fill`` (UNKNOWN). The result has the dtype of ``codes``.
    """
    out = np.full((size_cells, size_cells), fill, dtype=codes.dtype)
    map_r, map_c, win_r, win_c = _window_overlap(robot_cell, size_cells, codes.shape)
    out[win_r, win_c] = codes[map_r, map_c]
    return out


def unshift(window: np.ndarray, robot_cell: Cell, map_shape: tuple[int, int], fill: float = np.nan) -> np.ndarray:
    """Inverse of :func:`pad_shift`: the window's values placed back on a map of ``map_shape``.

    Map cells the window does not cover get ``fill`` (NaN by default, which thresholding reads as UNKNOWN), so a
    predictor's probability window comes back onto the map grid with no prediction outside it.
    """
    dtype = np.result_type(window.dtype, np.asarray(fill).dtype)
    out = np.full(map_shape, fill, dtype=dtype)
    map_r, map_c, win_r, win_c = _window_overlap(robot_cell, window.shape[0], map_shape)
    out[map_r, map_c] = window[win_r, win_c]
    return out


# ---- heading-up rotate + crop (policy observation) ---------------------------------------------------------------
def _ego_to_map_affine(
    center_cell: Cell, yaw_rad: float, size_cells: int, ego_origin_rc: tuple[int, int] = (0, 0)
) -> np.ndarray:
    """2×3 matrix taking ego (col, row) pixel coordinates to map (col, row) cell coordinates.

    Ego +row is the heading (cos ψ, sin ψ) in map (col=x, row=y); ego +col is the robot's right (sin ψ, −cos ψ).
    ``ego_origin_rc`` shifts the ego pixel (0, 0) to that ego (row, col), for warping a sub-window.
    """
    s, c = math.sin(yaw_rad), math.cos(yaw_rad)
    half = size_cells // 2
    d_row, d_col = ego_origin_rc[0] - half, ego_origin_rc[1] - half
    return np.array(
        [
            [s, c, center_cell[1] + d_col * s + d_row * c],
            [-c, s, center_cell[0] - d_col * c + d_row * s],
        ]
    )


def ego_to_map_cells(
    ego_rc: np.ndarray, center_cell: Cell, yaw_rad: float, size_cells: int = OBSERVATION_WINDOW_CELLS
) -> np.ndarray:
    """Map (row, col) coordinates (floats, cell centres at integers) of ego pixel coordinates ``ego_rc`` (…, 2)."""
    m = _ego_to_map_affine(center_cell, yaw_rad, size_cells)
    ego_rc = np.asarray(ego_rc, dtype=np.float64)
    col = m[0, 0] * ego_rc[..., 1] + m[0, 1] * ego_rc[..., 0] + m[0, 2]
    row = m[1, 0] * ego_rc[..., 1] + m[1, 1] * ego_rc[..., 0] + m[1, 2]
    return np.stack([row, col], axis=-1)


def map_to_ego_cells(
    map_rc: np.ndarray, center_cell: Cell, yaw_rad: float, size_cells: int = OBSERVATION_WINDOW_CELLS
) -> np.ndarray:
    """Inverse of :func:`ego_to_map_cells`: ego (row, col) coordinates of map coordinates ``map_rc`` (…, 2)."""
    s, c = math.sin(yaw_rad), math.cos(yaw_rad)
    half = size_cells // 2
    map_rc = np.asarray(map_rc, dtype=np.float64)
    d_row = map_rc[..., 0] - center_cell[0]
    d_col = map_rc[..., 1] - center_cell[1]
    # The linear part [[s, c], [-c, s]] (ego col, row → map col, row) is a rotation; its inverse is its transpose.
    ego_col = s * d_col - c * d_row + half
    ego_row = c * d_col + s * d_row + half
    return np.stack([ego_row, ego_col], axis=-1)


def rotate_crop(
    codes: np.ndarray, center_cell: Cell, yaw_rad: float, size_cells: int = OBSERVATION_WINDOW_CELLS
) -> np.ndarray:
    """Heading-up ``size_cells``² window of an int8 code map (nearest neighbour, outside the map = UNKNOWN).

    Ego pixel (row, col) takes the map cell nearest to :func:`ego_to_map_cells` of it. Only the part of the window
    that the rotated map can cover is warped (the rest is UNKNOWN by definition), which makes the 0.20 m layer —
    a small map in a large window — cheap.
    """
    if codes.dtype != CELL_DTYPE:
        raise TypeError(f"rotate_crop expects int8 cell codes, got {codes.dtype}")
    out = np.zeros((size_cells, size_cells), dtype=np.uint8)  # UNKNOWN == 0
    # Bounding box in the window of the map's rotated outline (plain floats: this runs every step).
    sin, cos, half = math.sin(yaw_rad), math.cos(yaw_rad), size_cells // 2
    rows, cols = codes.shape
    ego_rows, ego_cols = [], []
    for d_row in (-0.5 - center_cell[0], rows - 0.5 - center_cell[0]):
        for d_col in (-0.5 - center_cell[1], cols - 0.5 - center_cell[1]):
            ego_cols.append(sin * d_col - cos * d_row + half)
            ego_rows.append(cos * d_col + sin * d_row + half)
    r_lo = max(int(math.floor(min(ego_rows))) - 1, 0)
    r_hi = min(int(math.ceil(max(ego_rows))) + 2, size_cells)
    c_lo = max(int(math.floor(min(ego_cols))) - 1, 0)
    c_hi = min(int(math.ceil(max(ego_cols))) + 2, size_cells)
    if r_lo < r_hi and c_lo < c_hi:
        cv2.warpAffine(
            codes.view(np.uint8),  # opencv has no int8 warp: move the codes' bytes unchanged
            _ego_to_map_affine(center_cell, yaw_rad, size_cells, (r_lo, c_lo)),
            (c_hi - c_lo, r_hi - r_lo),
            dst=out[r_lo:r_hi, c_lo:c_hi],
            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=UNKNOWN,
        )
    return out.view(CELL_DTYPE)


# ---- inflation ---------------------------------------------------------------------------------------------------
def inflation_kernel(resolution_m: float, radius_m: float = INFLATION_RADIUS_M) -> np.ndarray:
    """Disk of cells whose centres lie within ``radius_m`` of the centre cell (uint8 0/1, odd square).

    Inflation is the binary dilation of the occupied cells by this disk (``cv2.dilate`` with it gives the same
    band, which the tests check).
    """
    r_cells = radius_m / resolution_m
    half = int(math.floor(r_cells + 1e-9))
    dy, dx = np.mgrid[-half : half + 1, -half : half + 1]
    return ((dy * dy + dx * dx) <= r_cells * r_cells + 1e-9).astype(np.uint8)


@njit(cache=True, inline="always")
def _inflated_code(code, count):
    if code == OCCUPIED:
        return OCCUPIED
    return NON_FLIGHT if count > 0 else code


@njit(cache=True)
def _inflate(codes, inflated, d_rows, d_cols):
    """inflated ← codes with NON_FLIGHT stamped on the non-occupied cells of each occupied cell's disk."""
    n_rows, n_cols = codes.shape
    inflated[:, :] = codes
    for i in range(n_rows):
        for j in range(n_cols):
            if codes[i, j] != OCCUPIED:
                continue
            for k in range(d_rows.shape[0]):
                ii = i + d_rows[k]
                jj = j + d_cols[k]
                if 0 <= ii < n_rows and 0 <= jj < n_cols and codes[ii, jj] != OCCUPIED:
                    inflated[ii, jj] = NON_FLIGHT


@njit(cache=True)
def _restamp(codes, inflated, count, i, j, delta, d_rows, d_cols):
    """Add ``delta`` to the occupied-neighbour count of the disk around (i, j) and re-code those cells."""
    for k in range(d_rows.shape[0]):
        ii = i + d_rows[k]
        jj = j + d_cols[k]
        if 0 <= ii < codes.shape[0] and 0 <= jj < codes.shape[1]:
            count[ii, jj] += delta
            inflated[ii, jj] = _inflated_code(codes[ii, jj], count[ii, jj])


@njit(cache=True)
def _update_cells(codes, inflated, count, counted, rows, cols, d_rows, d_cols):
    for k in range(rows.shape[0]):
        i = rows[k]
        j = cols[k]
        occupied = codes[i, j] == OCCUPIED
        if occupied != counted[i, j]:
            counted[i, j] = occupied
            _restamp(codes, inflated, count, i, j, 1 if occupied else -1, d_rows, d_cols)
        inflated[i, j] = _inflated_code(codes[i, j], count[i, j])


@lru_cache(maxsize=16)
def _disk_offsets(resolution_m: float, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) offsets of the inflation disk's cells."""
    kernel = inflation_kernel(resolution_m, radius_m)
    d_rows, d_cols = np.nonzero(kernel)
    half = kernel.shape[0] // 2
    return (d_rows - half).astype(np.int64), (d_cols - half).astype(np.int64)


def inflate_codes(codes: np.ndarray, resolution_m: float, radius_m: float = INFLATION_RADIUS_M) -> np.ndarray:
    """Mark the NON_FLIGHT band: every non-occupied cell within ``radius_m`` of an OCCUPIED cell.

    FREE and UNKNOWN cells in the band both become NON_FLIGHT (the vehicle may not fly there whatever is known
    about them); OCCUPIED cells stay OCCUPIED. Cells beyond the array edge count as not occupied.
    """
    codes = np.ascontiguousarray(codes, dtype=CELL_DTYPE)
    inflated = np.empty_like(codes)
    _inflate(codes, inflated, *_disk_offsets(resolution_m, radius_m))
    return inflated


class InflatedMap:
    """:func:`inflate_codes` of a code map, kept up to date cell by cell as that map changes.

    Each cell holds the number of occupied cells within the inflation disk around it; when a cell turns occupied
    (or stops being occupied) the counts of its disk change by one and those cells are re-coded. An update costs
    a few operations per changed cell, so the simulator refreshes the inflated high-res map every step in
    microseconds instead of inflating the whole map. Starts as the inflation of an all-UNKNOWN map; call
    :meth:`update_cells` with every cell of the source map that changed.
    """

    def __init__(self, shape: tuple[int, int], resolution_m: float, radius_m: float = INFLATION_RADIUS_M) -> None:
        self._d_rows, self._d_cols = _disk_offsets(resolution_m, radius_m)
        self.codes = np.zeros(shape, dtype=CELL_DTYPE)  # the inflated map
        self._count = np.zeros(shape, dtype=np.int32)
        self._counted = np.zeros(shape, dtype=np.bool_)

    def update_cells(self, codes: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        """Account for changes of the source map ``codes`` at the cells (rows[k], cols[k]) (int64 indices)."""
        if codes.shape != self.codes.shape or codes.dtype != CELL_DTYPE:
            raise ValueError(f"expected int8 codes of shape {self.codes.shape}, got {codes.dtype} {codes.shape}")
        _update_cells(codes, self.codes, self._count, self._counted, rows, cols, self._d_rows, self._d_cols)


# ---- policy observation ------------------------------------------------------------------------------------------
def one_hot_action(action: int, num_actions: int = NUM_ACTIONS) -> np.ndarray:
    """float32 one-hot vector of the last action."""
    if not 0 <= action < num_actions:
        raise ValueError(f"action must be in 0..{num_actions - 1}, got {action}")
    out = np.zeros(num_actions, dtype=np.float32)
    out[action] = 1.0
    return out


def encode_observation(
    high_inflated: np.ndarray,
    thres_inflated: np.ndarray,
    high_cell: Cell,
    low_cell: Cell,
    yaw_rad: float,
    last_action: int,
    size_cells: int = OBSERVATION_WINDOW_CELLS,
) -> dict[str, np.ndarray]:
    """The policy observation O = {high, thres, last_action} from already inflated maps (docs/design.md §5).

    * ``high``: int8 codes (FREE −1, UNKNOWN 0, OCCUPIED 1, NON_FLIGHT 2), ``size_cells``² heading-up window of
      the inflated 0.05 m observed map centred on the robot's cell ``high_cell``;
    * ``thres``: the same at 0.20 m of the inflated thresholded map (observed cells ∪ thresholded prediction;
      the observed low-res map when there is no predictor), centred on ``low_cell``;
    * ``last_action``: float32 one-hot of the previous action.

    Callers that do not maintain inflated maps use :func:`observation_from_maps`.
    """
    return {
        "high": rotate_crop(high_inflated, high_cell, yaw_rad, size_cells),
        "thres": rotate_crop(thres_inflated, low_cell, yaw_rad, size_cells),
        "last_action": one_hot_action(last_action),
    }


def observation_from_maps(
    high_codes: np.ndarray,
    thres_codes: np.ndarray,
    high_resolution_m: float,
    low_resolution_m: float,
    high_cell: Cell,
    low_cell: Cell,
    yaw_rad: float,
    last_action: int,
    radius_m: float = INFLATION_RADIUS_M,
) -> dict[str, np.ndarray]:
    """:func:`encode_observation` of the inflated maps: what the daemon calls once per decision."""
    return encode_observation(
        inflate_codes(high_codes, high_resolution_m, radius_m),
        inflate_codes(thres_codes, low_resolution_m, radius_m),
        high_cell,
        low_cell,
        yaw_rad,
        last_action,
    )
