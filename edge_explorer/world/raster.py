"""Rasterized buildings: occupancy, interior mask and 3-D height map on a :class:`GridSpec`.

Every later stage (simulator, mapping, benchmark, daemon) works on a :class:`PlanRaster`, whatever the source of
the building (vector JSON or ROS map_server image). Definitions (docs/design.md §4, §7):

* ``height_m``: top of the obstacle in each cell (0 = open floor); walls reach the ceiling.
* occupied (2-D plan): ``height_m >= TALL_HEIGHT_M`` — walls and tall furniture. Low furniture lives only in 3-D.
* interior: every cell not reachable from the grid border through free cells (4-connected), so the perimeter
  walls and the walls inside the outline are interior, as N_M requires.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from edge_explorer.errors import PlanError
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN, GridSpec, resolution_factor
from edge_explorer.world.plan import TALL_HEIGHT_M, FloorPlan, Rect

ROBOT_RADIUS_M = 0.25
GRID_MARGIN_M = 0.4  # ring of outside cells around the outline; a multiple of both map resolutions


@dataclass(frozen=True)
class PlanRaster:
    """A building on a grid. Arrays are indexed [row (y), col (x)]."""

    name: str
    grid: GridSpec
    height_m: np.ndarray  # float32, obstacle top per cell
    interior: np.ndarray  # bool
    ceiling_height_m: float

    @property
    def occupied(self) -> np.ndarray:
        return self.height_m >= TALL_HEIGHT_M

    def truth_codes(self) -> np.ndarray:
        """Ground-truth trinary map: OCCUPIED / FREE inside the building, UNKNOWN outside."""
        codes = np.full(self.grid.shape, UNKNOWN, dtype=CELL_DTYPE)
        codes[self.interior & self.occupied] = OCCUPIED
        codes[self.interior & ~self.occupied] = FREE
        return codes

    def coarsened(self, resolution_m: float) -> PlanRaster:
        """The same building at a coarser, nesting resolution (e.g. 0.05 m → 0.20 m).

        A coarse cell takes the tallest obstacle of its fine cells (an occupied fine cell makes it occupied — the
        rule the observed maps use). It is interior when one of its fine cells is, except on the building's outer
        boundary: a coarse cell that also holds outside cells counts only if a sensor inside can see into it (it
        holds a free interior cell or a wall face). Otherwise a sliver of perimeter wall that a 0.20 m cell
        straddles would count in N_M although no method can ever observe it; wall cells inside the outline still
        count, as docs/design.md §7 asks.
        """
        f = resolution_factor(self.grid.resolution_m, resolution_m)
        grid = self.grid.coarsened(f)
        free = self.interior & ~self.occupied
        face = self.interior & self.occupied & ndimage.binary_dilation(free, structure=np.ones((3, 3), bool))
        seeable = block_reduce_max(free | face, f, grid.shape)
        outside = block_reduce_max(~self.interior, f, grid.shape)
        interior = block_reduce_max(self.interior, f, grid.shape) & (seeable | ~outside)
        return PlanRaster(
            self.name, grid, block_reduce_max(self.height_m, f, grid.shape), interior, self.ceiling_height_m
        )


def block_reduce_max(fine: np.ndarray, factor: int, coarse_shape: tuple[int, int]) -> np.ndarray:
    """Max over ``factor``×``factor`` blocks, padding the fine array with its minimum where it does not divide."""
    rows, cols = coarse_shape
    padded = np.full((rows * factor, cols * factor), fine.min() if fine.size else 0, dtype=fine.dtype)
    padded[: fine.shape[0], : fine.shape[1]] = fine
    return padded.reshape(rows, factor, cols, factor).max(axis=(1, 3))


def plan_grid(plan: FloorPlan, resolution_m: float) -> GridSpec:
    """Grid covering the plan's outline plus a margin; its origin nests every resolution that divides 0.4 m."""
    b = plan.bounds()
    x0 = np.floor(b.x_min_m / resolution_m) * resolution_m - GRID_MARGIN_M
    y0 = np.floor(b.y_min_m / resolution_m) * resolution_m - GRID_MARGIN_M
    cols = int(np.ceil((b.x_max_m + GRID_MARGIN_M - x0) / resolution_m - 1e-9))
    rows = int(np.ceil((b.y_max_m + GRID_MARGIN_M - y0) / resolution_m - 1e-9))
    return GridSpec((float(x0), float(y0)), resolution_m, (rows, cols))


def _cells_overlapping(grid: GridSpec, rect: Rect) -> tuple[slice, slice]:
    """Index slices of every cell that overlaps ``rect`` with positive area."""
    x0, y0 = grid.origin_xy
    r = grid.resolution_m
    eps = 1e-9
    c0 = max(int(np.floor((rect.x_min_m - x0) / r + eps)), 0)
    c1 = min(int(np.ceil((rect.x_max_m - x0) / r - eps)), grid.shape[1])
    r0 = max(int(np.floor((rect.y_min_m - y0) / r + eps)), 0)
    r1 = min(int(np.ceil((rect.y_max_m - y0) / r - eps)), grid.shape[0])
    return slice(r0, r1), slice(c0, c1)


def interior_from_occupancy(blocked: np.ndarray) -> np.ndarray:
    """Cells not reachable from the array border through non-blocked cells (4-connectivity)."""
    outside_seed = np.zeros_like(blocked, dtype=bool)
    outside_seed[0, :] = outside_seed[-1, :] = True
    outside_seed[:, 0] = outside_seed[:, -1] = True
    outside_seed &= ~blocked
    outside = ndimage.binary_propagation(outside_seed, mask=~blocked)
    return ~outside


def rasterize(plan: FloorPlan, resolution_m: float) -> PlanRaster:
    """Rasterize a vector plan at any resolution.

    Walls and furniture mark every cell they overlap (thin walls never vanish at coarse resolutions); doors then
    clear every cell they overlap, so a doorway is never narrower in the raster than in the plan.
    """
    if not (resolution_m > 0):
        raise PlanError(f"{plan.name}: resolution must be positive, got {resolution_m}")
    grid = plan_grid(plan, resolution_m)
    height = np.zeros(grid.shape, dtype=np.float32)
    for wall in plan.walls:
        height[_cells_overlapping(grid, wall)] = plan.ceiling_height_m
    for door in plan.doors:
        height[_cells_overlapping(grid, door)] = 0.0
    for item in plan.furniture:
        rows, cols = _cells_overlapping(grid, item.rect)
        height[rows, cols] = np.maximum(height[rows, cols], item.height_m)
    interior = interior_from_occupancy(height >= TALL_HEIGHT_M)
    raster = PlanRaster(plan.name, grid, height, interior, plan.ceiling_height_m)
    _check_outline_closed(plan, raster)
    return raster


def _check_outline_closed(plan: FloorPlan, raster: PlanRaster) -> None:
    pts = np.array(plan.outline, dtype=np.float64)
    outline_area_m2 = 0.5 * abs(np.dot(pts[:, 0], np.roll(pts[:, 1], 1)) - np.dot(pts[:, 1], np.roll(pts[:, 0], 1)))
    interior_area_m2 = float(raster.interior.sum()) * raster.grid.resolution_m**2
    if interior_area_m2 < 0.9 * outline_area_m2:
        raise PlanError(
            f"{plan.name}: the perimeter walls do not close the outline (interior {interior_area_m2:.1f} m², "
            f"outline {outline_area_m2:.1f} m²); close every gap in the perimeter"
        )


def clearance_m(raster: PlanRaster) -> np.ndarray:
    """Distance from each cell's centre to the nearest occupied cell's edge, in metres (0 on occupied cells)."""
    occ = raster.occupied
    if not occ.any():
        return np.full(occ.shape, np.inf, dtype=np.float32)
    cells = cv2.distanceTransform((~occ).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # exact Euclidean
    return (np.maximum(cells - 0.5, 0.0) * raster.grid.resolution_m).astype(np.float32)


def configuration_space(raster: PlanRaster, robot_radius_m: float = ROBOT_RADIUS_M) -> np.ndarray:
    """Interior cells where a robot of ``robot_radius_m`` can stand."""
    return raster.interior & (clearance_m(raster) >= robot_radius_m)


def check_connected(raster: PlanRaster, robot_radius_m: float = ROBOT_RADIUS_M, source: str | None = None) -> None:
    """Raise :class:`PlanError` unless the interior free space is one connected region at the robot's radius."""
    src = source or raster.name
    cspace = configuration_space(raster, robot_radius_m)
    labels, count = ndimage.label(cspace, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        raise PlanError(f"{src}: no interior free space where a robot of radius {robot_radius_m} m fits")
    if count > 1:
        sizes = np.bincount(labels.ravel())[1:] * raster.grid.resolution_m**2
        raise PlanError(
            f"{src}: interior free space is split into {count} regions at robot radius {robot_radius_m} m "
            f"(areas {', '.join(f'{s:.2f}' for s in sorted(sizes, reverse=True)[:5])} m²); "
            "every room needs a door at least 0.80 m wide"
        )
