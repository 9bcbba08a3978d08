"""Maps that grow as the vehicle observes: nothing is sized from a plan (docs/design.md §5, "Maps that grow").

:class:`GrowingMaps` is a :class:`~edge_explorer.mapping.voxels.VoxelMaps` (same fusion, same kernels) whose boxes
follow the vehicle:

* the **0.20 m voxel map** starts as a small box around take-off and grows whenever a frame's camera comes within
  sensor range + ``margin_m`` of its edge (the rays of a frame never reach farther: hits and free space are cut at
  ``max_range_m``). A side that must grow grows past what is needed by half the box's length, at most
  ``step_max_m``, so reallocations are few (amortised like a doubling array) and the slack is bounded: along each
  axis the box spans at most the flown extent + 2 × (range + margin) + 2 × ``step_max_m`` (:func:`footprint_bound`);
* the **0.05 m voxel map** is a ``window_m`` × ``window_m`` window (dense 3-D at 0.05 m over a whole floor would be
  ~0.7 GB). When the camera comes within range + margin of the window's edge, the window is recentred on it: what
  the old and new window share keeps its log-odds, and before that the window's projection is folded into a
  **persistent 2-D 0.05 m map** that grows with the 0.20 m map's box, so what left the window survives in 2-D;
* the **flown footprint** (cells the vehicle's body has been in, counted free unless seen occupied) lives on that
  persistent 2-D grid too.

:meth:`GrowingMaps.project` gives the planners' 2-D maps over everything seen: the persistent map with the
window's projection laid over it (the window wins where it knows the cell), and the 0.20 m map's projection.

All boxes sit on one lattice anchored at take-off snapped to 0.20 m (so the 2-D grids nest with a plan grid whose
origin is on that lattice, as the catalogue's are); voxel coordinates are counted from the anchor whatever the box
(:meth:`~edge_explorer.mapping.voxels.VoxelGrid.reframe`), so a frame fused into a grown or moved box updates
exactly the voxels it would update in one large fixed box. Fusion cost per frame depends on the frame, not on the
map's size; a growth or a recentring costs one copy of the box (a few ms), rarely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from edge_explorer.mapping.projection import HeightBand, project, project_box
from edge_explorer.mapping.voxels import UNKNOWN_LOGODDS, FusionConfig, VoxelGrid, VoxelMaps, VoxelRegion
from edge_explorer.world.grid import CELL_DTYPE, FREE, HIGH_RES_M, LOW_RES_M, UNKNOWN, GridSpec


@dataclass(frozen=True)
class GrowthConfig:
    """How :class:`GrowingMaps` grows: the 0.05 m window's side, the first 0.20 m box's side (both centred on
    take-off), the margin kept beyond sensor range around the camera, and the most a side grows past what it needs.
    Lengths are rounded to whole 0.20 m cells."""

    window_m: float = 24.0
    start_m: float = 16.0
    margin_m: float = 1.0
    step_max_m: float = 16.0

    def __post_init__(self) -> None:
        if not (self.window_m > 0 and self.start_m > 0 and min(self.margin_m, self.step_max_m) >= 0):
            raise ValueError("window_m and start_m must be positive, margin_m and step_max_m ≥ 0")


def _cells(length_m: float, resolution_m: float) -> int:
    return int(math.ceil(length_m / resolution_m - 1e-9))


class GrowingMaps(VoxelMaps):
    """The voxel maps of one flight, growing from take-off at (``x_m``, ``y_m``); ``z_range_m`` is the height they
    cover. Fuse frames as into :class:`VoxelMaps`; ``high`` is the 0.05 m window, ``low`` the growing 0.20 m map,
    :attr:`seen` / :attr:`flown` the persistent 2-D maps on :attr:`grid`; ``band`` is the projection's band (the
    window is folded into :attr:`seen` over it)."""

    def __init__(
        self,
        x_m: float,
        y_m: float,
        z_range_m: tuple[float, float],
        config: FusionConfig | None = None,
        growth: GrowthConfig = GrowthConfig(),
        band: HeightBand | None = None,
    ) -> None:
        config = config if config is not None else FusionConfig()
        self.growth = growth
        self.band = band if band is not None else HeightBand()  # what a recentring folds into the 2-D map
        self.factor = int(round(LOW_RES_M / HIGH_RES_M))
        anchor = (math.floor(x_m / LOW_RES_M) * LOW_RES_M, math.floor(y_m / LOW_RES_M) * LOW_RES_M, z_range_m[0])
        z_size = _cells(z_range_m[1] - z_range_m[0], LOW_RES_M) * LOW_RES_M
        super().__init__(VoxelRegion(anchor, (LOW_RES_M, LOW_RES_M, z_size)), config, HIGH_RES_M, LOW_RES_M)
        self.anchor_xy = anchor[:2]
        self.reach_m = config.max_range_m + growth.margin_m  # how far from the camera a frame can write
        if growth.window_m < 2 * (self.reach_m + LOW_RES_M):
            raise ValueError(f"a {growth.window_m} m window cannot hold a camera's reach of {self.reach_m} m around it")
        self.seen = np.zeros((0, 0), dtype=CELL_DTYPE)  # persistent 0.05 m codes on self.grid
        self.flown = np.zeros((0, 0), dtype=np.uint8)  # 1 where the vehicle's body has been
        self._composed: np.ndarray | None = None  # project()'s 0.05 m map, kept current in place (None: rebuild)
        self._flown_box: tuple[int, int, int, int] | None = None  # rows, cols [r0, r1) × [c0, c1) flown since
        # project()'s projections of the window and of the 0.20 m map, kept current in place (None: rebuild), and
        # the box (x0, x1, y0, y1 in metres) that frames may have written since it last ran
        self._window_codes: np.ndarray | None = None
        self._low_codes: np.ndarray | None = None
        self._written: tuple[float, float, float, float] | None = None
        self.growths = 0
        self.recentrings = 0
        row, col = self.low.index_of(x_m, y_m, anchor[2])[:2]
        half = _cells(growth.start_m / 2, LOW_RES_M)
        self._reframe_low(row - half, col - half, 2 * half, 2 * half)
        self._recentre(x_m, y_m, fold=False)

    # ---- what a frame needs -------------------------------------------------------------------------------------

    def _before_insert(self, position_m: np.ndarray) -> None:
        x, y = float(position_m[0]), float(position_m[1])
        self.ensure_covers(x, y)
        # a frame writes only voxels within sensor range of its camera (module docstring), all inside reach_m
        box = (x - self.reach_m, x + self.reach_m, y - self.reach_m, y + self.reach_m)
        if self._written is not None:
            old = self._written
            box = (min(box[0], old[0]), max(box[1], old[1]), min(box[2], old[2]), max(box[3], old[3]))
        self._written = box

    def ensure_covers(self, x_m: float, y_m: float) -> None:
        """Grow the 0.20 m map and move the 0.05 m window so both hold everything a camera at (x, y) can see."""
        (r0, c0), (r1, c1) = self._needed(self.low, x_m, y_m)
        (lr0, lc0), (rows, cols) = self.low.offset_cells, self.low.shape[:2]
        if r0 < lr0 or c0 < lc0 or r1 > lr0 + rows or c1 > lc0 + cols:
            step = _cells(self.growth.step_max_m, LOW_RES_M)
            slack_r, slack_c = min(rows // 2, step), min(cols // 2, step)
            new_r0 = min(lr0, r0 - slack_r) if r0 < lr0 else lr0
            new_c0 = min(lc0, c0 - slack_c) if c0 < lc0 else lc0
            new_r1 = max(lr0 + rows, r1 + slack_r) if r1 > lr0 + rows else lr0 + rows
            new_c1 = max(lc0 + cols, c1 + slack_c) if c1 > lc0 + cols else lc0 + cols
            self._reframe_low(new_r0, new_c0, new_r1 - new_r0, new_c1 - new_c0)
            self.growths += 1
        (r0, c0), (r1, c1) = self._needed(self.high, x_m, y_m)
        (hr0, hc0), (rows, cols) = self.high.offset_cells, self.high.shape[:2]
        if r0 < hr0 or c0 < hc0 or r1 > hr0 + rows or c1 > hc0 + cols:
            self._recentre(x_m, y_m, fold=True)
            self.recentrings += 1

    def _needed(self, vox: VoxelGrid, x_m: float, y_m: float) -> tuple[tuple[int, int], tuple[int, int]]:
        """Anchor cells [(row0, col0), (row1, col1)) within reach of a camera at (x, y) on ``vox``'s lattice."""
        r = vox.resolution_m
        ax, ay = self.anchor_xy
        lo = (math.floor((y_m - self.reach_m - ay) / r), math.floor((x_m - self.reach_m - ax) / r))
        hi = (math.floor((y_m + self.reach_m - ay) / r) + 1, math.floor((x_m + self.reach_m - ax) / r) + 1)
        return lo, hi

    def _reframe_low(self, row0: int, col0: int, rows: int, cols: int) -> None:
        """The 0.20 m map over low cells [row0, +rows) × [col0, +cols), the persistent 2-D maps over the same box."""
        old_grid, old_seen, old_flown = (self.grid if self.seen.size else None), self.seen, self.flown
        self.low.reframe(row0, col0, rows, cols)
        f = self.factor
        self.seen = np.full((rows * f, cols * f), UNKNOWN, dtype=CELL_DTYPE)
        self.flown = np.zeros((rows * f, cols * f), dtype=np.uint8)
        self._composed = None
        self._low_codes = None
        if old_grid is not None:
            _paste(self.seen, self.grid, old_seen, old_grid, keep_unknown=False)
            _paste(self.flown, self.grid, old_flown, old_grid, keep_unknown=False)
        z_size = self.region.size_xyz_m[2]
        origin = (*self.grid.origin_xy, self.region.origin_xyz_m[2])
        self.region = VoxelRegion(origin, (cols * LOW_RES_M, rows * LOW_RES_M, z_size))

    def _recentre(self, x_m: float, y_m: float, fold: bool) -> None:
        """Centre the 0.05 m window on (x, y) (on whole 0.20 m cells), folding its projection into :attr:`seen`."""
        if fold:
            self.fold()
        self._window_codes = None
        n = _cells(self.growth.window_m, LOW_RES_M) * self.factor
        row, col = self.low.index_of(x_m, y_m, self.region.origin_xyz_m[2])[:2]
        lr0, lc0 = self.low.offset_cells
        f = self.factor
        row0, col0 = (lr0 + row) * f - n // 2, (lc0 + col) * f - n // 2
        if self.high.shape[:2] == (n, n):  # moved in place: no second window alive, even for a moment
            old_row0, old_col0 = self.high.offset_cells
            _shift(self.high.log_odds, row0 - old_row0, col0 - old_col0, UNKNOWN_LOGODDS)
            self.high._stamp.fill(0)
            self.high.offset_cells = (row0, col0)
        else:
            self.high.reframe(row0, col0, n, n)

    def fold(self) -> None:
        """Lay the window's projection over the persistent 2-D map (where the window knows the cell)."""
        codes, grid = project(self.high, self.band)
        _paste(self.seen, self.grid, codes, grid, keep_unknown=True)
        self._composed = None

    # ---- what the planners read ---------------------------------------------------------------------------------

    @property
    def grid(self) -> GridSpec:
        """The persistent 0.05 m grid: the 0.20 m map's box at 0.05 m (same origin)."""
        rows, cols = self.low.shape[:2]
        return GridSpec(self.low.grid.origin_xy, HIGH_RES_M, (rows * self.factor, cols * self.factor))

    def mark_flown(self, x_m: float, y_m: float, radius_m: float) -> None:
        """Every 0.05 m cell within ``radius_m`` of (x, y) has been flown through (free unless seen occupied)."""
        radius_cells = int(radius_m / HIGH_RES_M)
        if radius_cells <= 0:
            return
        row, col = (int(v) for v in self.grid.cell_of(x_m, y_m))
        cv2.circle(self.flown, (col, row), radius_cells, 1, thickness=-1)
        box = (row - radius_cells, row + radius_cells + 1, col - radius_cells, col + radius_cells + 1)
        if self._flown_box is not None:
            old = self._flown_box
            box = (min(box[0], old[0]), max(box[1], old[1]), min(box[2], old[2]), max(box[3], old[3]))
        self._flown_box = box

    def project(self) -> tuple[np.ndarray, GridSpec, np.ndarray, GridSpec]:
        """(0.05 m codes, their grid, 0.20 m codes, their grid) over the whole box (same origin), projected over
        ``band``; the flown footprint counts free at 0.05 m where nothing was seen. The grids change only when the
        box grows (planners that keep cell indices across decisions must start afresh then).

        The 0.05 m map is the maps' own array, brought up to date in place by the next call: copy it to keep it,
        never write to it (it stays writable, as every other map is, so the numba kernels that read it see one
        argument type, :mod:`edge_explorer.runtime.kernels`). Between two calls only the window's cells and the
        newly flown ones can change (:attr:`seen` changes only when the window is folded into it or the box grows,
        and then the whole map is composed anew), so a call composes those alone, at a cost that does not grow with
        the box (composing the whole 0.05 m map of a 290 × 60 m box, 7 M cells, takes ~4–7 ms on this project's
        2-core machine)."""
        window, window_grid, window_box = self._projected(self.high, self._window_codes)
        self._window_codes = window
        grid = self.grid
        row0 = int(round((window_grid.origin_xy[1] - grid.origin_xy[1]) / HIGH_RES_M))
        col0 = int(round((window_grid.origin_xy[0] - grid.origin_xy[0]) / HIGH_RES_M))
        rows, cols = self.seen.shape
        if self._composed is None:
            self._composed = np.empty_like(self.seen)
            boxes = [(0, rows, 0, cols)]
        else:
            boxes = [(row0 + window_box[0], row0 + window_box[1], col0 + window_box[2], col0 + window_box[3])]
            if self._flown_box is not None:
                boxes.append(self._flown_box)
        for r0, r1, c0, c1 in boxes:
            box = (max(r0, 0), min(r1, rows), max(c0, 0), min(c1, cols))
            _compose(self.seen, self.flown, window, row0, col0, self._composed, *box)
        self._flown_box = None
        low, low_grid, _ = self._projected(self.low, self._low_codes)
        self._low_codes = low
        self._written = None
        return self._composed, grid, low.copy(), low_grid

    def _projected(
        self, vox: VoxelGrid, codes: np.ndarray | None
    ) -> tuple[np.ndarray, GridSpec, tuple[int, int, int, int]]:
        """(``vox``'s projection, its grid, the box [r0, r1) × [c0, c1) of cells brought up to date): ``codes``
        (the previous call's, or None) reprojected where frames wrote since (:attr:`_written`), or a new
        projection."""
        grid = vox.grid
        if codes is None or codes.shape != grid.shape:
            codes, grid = project(vox, self.band)
            return codes, grid, (0, grid.shape[0], 0, grid.shape[1])
        if self._written is None:
            return codes, grid, (0, 0, 0, 0)
        x0, x1, y0, y1 = self._written
        (r0, c0), (r1, c1) = grid.cell_of(x0, y0), grid.cell_of(x1, y1)
        box = (max(int(r0), 0), min(int(r1) + 1, grid.shape[0]), max(int(c0), 0), min(int(c1) + 1, grid.shape[1]))
        project_box(vox, self.band, codes, box[:2], box[2:])
        return codes, grid, box

    def nbytes(self) -> int:
        """Bytes of every map array (both voxel maps with their frame stamps, the persistent 2-D maps)."""
        arrays = (self.high.log_odds, self.high._stamp, self.low.log_odds, self.low._stamp, self.seen, self.flown)
        return sum(a.nbytes for a in arrays)


def footprint_bound(
    extent_xy_m: tuple[float, float],
    z_range_m: tuple[float, float],
    config: FusionConfig | None = None,
    growth: GrowthConfig = GrowthConfig(),
) -> int:
    """The most bytes :meth:`GrowingMaps.nbytes` can reach on a flight whose camera stays within a box of
    ``extent_xy_m`` (e.g. a building's outline), while a box is being replaced (old and new arrays alive) included.

    Along each axis the 0.20 m box spans at most max(extent + 2 reach, start + 1 cell) + 2 × step_max (+ a cell of
    rounding each side); reach = range + margin. The window is fixed.
    """
    reach = (config if config is not None else FusionConfig()).max_range_m + growth.margin_m
    layers_low = _cells(z_range_m[1] - z_range_m[0], LOW_RES_M)
    factor = int(round(LOW_RES_M / HIGH_RES_M))
    spans = [
        _cells(max(e + 2 * reach, growth.start_m + LOW_RES_M) + 2 * growth.step_max_m, LOW_RES_M) + 2
        for e in extent_xy_m
    ]
    low_cells = spans[0] * spans[1]
    low_bytes = low_cells * layers_low * 4  # int16 log-odds + uint16 stamps
    plane_bytes = low_cells * factor * factor * 2  # int8 codes + uint8 footprint at 0.05 m
    window = _cells(growth.window_m, LOW_RES_M) * factor
    window_bytes = window * window * layers_low * factor * 4
    # A growth holds the old box beside the new one (log-odds, then the 2-D maps); the window moves in place.
    return 2 * (low_bytes + plane_bytes) + window_bytes


@numba.njit(cache=True, nogil=True)
def _shift(a, dr, dc, fill):
    """a[i, j] ← a[i + dr, j + dc] in place (``fill`` where that lies outside), each cell read before it is
    overwritten."""
    rows, cols = a.shape[0], a.shape[1]
    row_order = range(rows) if dr >= 0 else range(rows - 1, -1, -1)
    col_order = range(cols) if dc >= 0 else range(cols - 1, -1, -1)
    for i in row_order:
        si = i + dr
        for j in col_order:
            sj = j + dc
            if 0 <= si < rows and 0 <= sj < cols:
                a[i, j, :] = a[si, sj, :]
            else:
                a[i, j, :] = fill


@numba.njit(cache=True, nogil=True)
def _compose(seen, flown, window, row0, col0, out, r0, r1, c0, c1):
    """out ← ``seen`` with ``window`` (its cell (0, 0) at (row0, col0)) laid over it where the window knows the
    cell, then FREE where still UNKNOWN and flown, over rows [r0, r1) and columns [c0, c1): one pass."""
    w_rows, w_cols = window.shape
    for i in range(r0, r1):
        wi = i - row0
        for j in range(c0, c1):
            v = seen[i, j]
            wj = j - col0
            if 0 <= wi < w_rows and 0 <= wj < w_cols and window[wi, wj] != UNKNOWN:
                v = window[wi, wj]
            if v == UNKNOWN and flown[i, j] != 0:
                v = FREE
            out[i, j] = v


def _paste(dst: np.ndarray, dst_grid: GridSpec, src: np.ndarray, src_grid: GridSpec, keep_unknown: bool) -> None:
    """Copy ``src`` onto ``dst`` where their grids (same resolution, whole cells apart) overlap; with
    ``keep_unknown`` only the known (non-UNKNOWN) cells of ``src``."""
    r = dst_grid.resolution_m
    dcol = int(round((src_grid.origin_xy[0] - dst_grid.origin_xy[0]) / r))
    drow = int(round((src_grid.origin_xy[1] - dst_grid.origin_xy[1]) / r))
    r0, c0 = max(0, drow), max(0, dcol)
    r1, c1 = min(dst.shape[0], drow + src.shape[0]), min(dst.shape[1], dcol + src.shape[1])
    if r1 <= r0 or c1 <= c0:
        return
    part = src[r0 - drow : r1 - drow, c0 - dcol : c1 - dcol]
    if keep_unknown:
        view = dst[r0:r1, c0:c1]
        np.copyto(view, part, where=part != UNKNOWN)
    else:
        dst[r0:r1, c0:c1] = part
