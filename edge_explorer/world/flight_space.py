"""One clearance, one truth: where the vehicle can fly, and which part of a building it can ever observe.

Every stage that asks "can the vehicle be here?" answers with this module (issue #18): the plan loaders and N_M
(:func:`restrict_to_flight_space`), the simulator's start sampler (:func:`reachable_cells`), the planners'
planning grid and the daemon's safety check (:func:`centre_clearance_m`, :func:`planning_cells` through
:class:`~edge_explorer.plan.follow.FreeSpace` and :class:`~edge_explorer.plan.graph.Traversable`).

Definitions
-----------
* **Clearance** of a cell: the distance from its centre to the centre of the nearest occupied cell
  (:func:`centre_clearance_m`, OpenCV's exact Euclidean distance transform) — the rule the inflated maps' NON_FLIGHT
  band uses, so ``clearance <= robot radius`` is exactly that band.
* **Planning cell** (:func:`planning_cells`): a ``factor`` × ``factor`` block of 0.05 m cells (0.10 m) that is all
  known FREE and whose *smallest* clearance is at least ``robot radius + safety margin`` (0.30 m). The vehicle's
  centre only ever travels through planning cells, so a doorway is crossable when its free width is at least about
  ``2 · 0.30 m`` plus the coarsening — narrower passages are walls for the planner, and here too.
* **Reachable** (:func:`reachable_cells`): the 0.05 m cells of the largest 8-connected component of planning
  cells of the ground truth — where a flight can go.
* **Observable** (:func:`observable_cells`): cells a sensor of range ``VIEW_RANGE_M`` sees from some reachable
  position, turning a full circle: free cells its rays cross and the occupied cells they stop at (wall faces);
  rays are sampled every half cell.
  Gaps of up to 0.20 m in a wall line (drawing artefacts of real plans) count as wall here: seeing through one
  needs a viewpoint no planner aims for.
  Views come from reachable cells on a lattice of ``VIEW_SPACING_M``; a cell seen only through a slit from
  between two lattice points may be missed, which errs on the side of not counting it.

N_M (docs/design.md §7) counts the observable interior: a room behind a doorway narrower than the vehicle still counts
as far as it can be seen through the doorway; the inside of a thick wall, a sliver between two wall lines, or a
room with no doorway at all cannot be observed by any flight and is dropped (:class:`FlightSpace` reports its
area, ``plans check`` prints it and ``plans show`` draws it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy import ndimage

from edge_explorer.errors import PlanError
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster

VIEW_RANGE_M = 4.5  # the planar sensor's range (vehicle.sensor.SensorConfig.range_m takes its default from here)
VIEW_SPACING_M = 0.5  # lattice of reachable view points for :func:`observable_cells`
SLIT_CELLS = 2  # gaps in a wall up to 2·SLIT_CELLS cells (0.20 m) are closed before looking through them
_RAY_GAP_CELLS = 0.9  # neighbouring rays at most this far apart at full range: no cell in range is skipped
_RAY_STEP_CELLS = 0.5  # samples along a ray
_SOURCES_PER_BLOCK = 4096  # view points cast at once by observable_cells


@dataclass(frozen=True)
class FlightClearance:
    """How close to an obstacle the vehicle's centre may come, and on which grid the planners check it."""

    robot_radius_m: float = ROBOT_RADIUS_M
    safety_margin_m: float = 0.05  # mean motions keep this beyond the robot radius (the follower's hard margin)
    planning_factor: int = 2  # planning cell = factor × factor cells of the 0.05 m map

    def __post_init__(self) -> None:
        if self.robot_radius_m <= 0 or self.safety_margin_m < 0 or self.planning_factor < 1:
            raise ValueError("robot_radius_m must be > 0, safety_margin_m ≥ 0 and planning_factor ≥ 1")

    @property
    def safe_distance_m(self) -> float:
        """Closest the vehicle's centre may be planned to an obstacle's centre."""
        return self.robot_radius_m + self.safety_margin_m


FLIGHT_CLEARANCE = FlightClearance()


def centre_clearance_m(occupied: np.ndarray, resolution_m: float) -> np.ndarray:
    """Distance from each cell's centre to the nearest occupied cell's centre, in metres; inf without obstacles."""
    if not occupied.any():
        return np.full(occupied.shape, np.inf, dtype=np.float32)
    cells = cv2.distanceTransform((~occupied).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    cells *= np.float32(resolution_m)  # in place: on a whole floor's map a copy is megabytes more for a moment
    return cells


def block_reduce(fine: np.ndarray, factor: int, combine: np.ufunc, pad_value: float | bool) -> np.ndarray:
    """``combine`` (np.minimum, np.logical_and) over factor × factor blocks; missing cells take ``pad_value``."""
    rows, cols = -(-fine.shape[0] // factor), -(-fine.shape[1] // factor)
    padded = np.full((rows * factor, cols * factor), pad_value, dtype=fine.dtype)
    padded[: fine.shape[0], : fine.shape[1]] = fine
    out = padded[::factor, ::factor].copy()
    for di in range(factor):
        for dj in range(factor):
            combine(out, padded[di::factor, dj::factor], out=out)
    return out


def planning_cells(
    known_free: np.ndarray, clearance_m: np.ndarray, safe_distance_m: float, factor: int
) -> tuple[np.ndarray, np.ndarray]:
    """(traversable mask, smallest clearance) of each planning cell, as the module docstring defines them."""
    clearance = block_reduce(clearance_m, factor, np.minimum, np.float32(0.0))
    all_free = block_reduce(known_free, factor, np.logical_and, False)
    return all_free & (clearance >= safe_distance_m), clearance


def reachable_cells(raster: PlanRaster, clearance: FlightClearance = FLIGHT_CLEARANCE) -> np.ndarray:
    """Bool on the raster's grid: the fine cells of the largest connected set of planning cells of the truth.

    Raises :class:`PlanError` when the building has no planning cell at all (no room wide enough to fly in)."""
    free = raster.interior & ~raster.occupied
    factor = clearance.planning_factor
    mask, _ = planning_cells(
        free, centre_clearance_m(raster.occupied, raster.grid.resolution_m), clearance.safe_distance_m, factor
    )
    labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        raise PlanError(
            f"{raster.name}: no free space where the vehicle's centre keeps {clearance.safe_distance_m:.2f} m "
            "from every wall; the plan has no room to fly in"
        )
    main = labels == int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    fine = np.repeat(np.repeat(main, factor, axis=0), factor, axis=1)[: free.shape[0], : free.shape[1]]
    return fine & free


def observable_cells(raster: PlanRaster, reachable: np.ndarray, range_m: float = VIEW_RANGE_M) -> np.ndarray:
    """Bool on the raster's grid: what a full turn of the sensor shows from the reachable view lattice.

    Rays are sampled every half cell, all view points at once per direction (numpy only: loading a plan compiles
    nothing, so the daemon's process and the start pose's JIT-less child load plans as fast as the benchmark).
    Every view point is a cell's centre, so one direction's samples lie at the same offsets in cells from every
    view point: they are computed once per direction, and the map is padded with wall by the sensor's range so
    that a ray stops at its border without a test per sample (2–3 × faster than casting each view point's rays on
    their own, with the same cells seen)."""
    res = raster.grid.resolution_m
    step = max(int(round(VIEW_SPACING_M / res)), 1)
    lattice = np.zeros_like(reachable)
    lattice[::step, ::step] = True
    sources = np.argwhere(reachable & lattice)
    if len(sources) == 0:  # a reachable set thinner than the lattice: look from every reachable cell
        sources = np.argwhere(reachable)
    # slits in a wall line (drawing gaps) are no windows: a view through one needs a viewpoint no planner aims for,
    # so the cells behind would count in N_M and stay unseen
    slit = np.ones((2 * SLIT_CELLS + 1,) * 2, dtype=bool)
    walls = ndimage.binary_closing(raster.occupied, structure=slit, border_value=1) | raster.occupied
    range_c = range_m / res
    pad = int(math.ceil(range_c)) + 1
    padded_walls = np.pad(walls, pad, constant_values=True)  # beyond the map's border a ray stops, as at a wall
    n_cols = padded_walls.shape[1]
    flat_walls = padded_walls.ravel()
    view_points = (sources[:, 0] + pad) * n_cols + (sources[:, 1] + pad)
    along = np.arange(0.0, range_c, _RAY_STEP_CELLS, dtype=np.float32)
    n_rays = int(math.ceil(2.0 * math.pi * range_c / _RAY_GAP_CELLS))
    seen = np.zeros(flat_walls.size, dtype=bool)
    # view points in blocks, so the per-ray arrays stay a few MB on a 270 m floor (all at once they peaked at
    # ~250 MB there); the cells seen are the same
    for block in range(0, len(view_points), _SOURCES_PER_BLOCK):
        block_points = view_points[block : block + _SOURCES_PER_BLOCK, None]
        for angle in 2.0 * math.pi * np.arange(n_rays) / n_rays:
            rows = np.floor(np.float32(0.5) + along * np.float32(math.sin(angle))).astype(np.int64)
            cols = np.floor(np.float32(0.5) + along * np.float32(math.cos(angle))).astype(np.int64)
            offsets = rows * n_cols + cols
            offsets = offsets[np.r_[True, offsets[1:] != offsets[:-1]]]  # a cell sampled twice in a row, once
            flat = block_points + offsets  # (view points, cells along the ray) on the padded map
            wall = flat_walls[flat]
            first_wall = np.where(wall.any(axis=1), wall.argmax(axis=1), len(offsets))
            seen[flat[np.arange(len(offsets)) <= first_wall[:, None]]] = True  # up to and including the first wall
    return seen.reshape(padded_walls.shape)[pad:-pad, pad:-pad] | reachable


@dataclass(frozen=True)
class FlightSpace:
    """A building's flyable and observable space, and what N_M leaves out."""

    reachable: np.ndarray  # bool, 0.05 m: where the vehicle's centre can go
    observable: np.ndarray  # bool, 0.05 m: what it can see from there (the kept interior)
    dropped: np.ndarray  # bool, 0.05 m: interior cells neither reachable nor observable
    dropped_free_m2: float  # free floor among them (closed rooms, slivers between walls)
    dropped_wall_m2: float  # wall among them (the inside of thick walls)


def flight_space(raster: PlanRaster, clearance: FlightClearance = FLIGHT_CLEARANCE) -> FlightSpace:
    """Reachable and observable space of ``raster`` (see the module docstring)."""
    reachable = reachable_cells(raster, clearance)
    observable = observable_cells(raster, reachable) & raster.interior
    dropped = raster.interior & ~observable
    cell_m2 = raster.grid.resolution_m**2
    return FlightSpace(
        reachable=reachable,
        observable=observable,
        dropped=dropped,
        dropped_free_m2=float((dropped & ~raster.occupied).sum() * cell_m2),
        dropped_wall_m2=float((dropped & raster.occupied).sum() * cell_m2),
    )


def restrict_to_flight_space(
    raster: PlanRaster, clearance: FlightClearance = FLIGHT_CLEARANCE
) -> tuple[PlanRaster, FlightSpace]:
    """The same building with its interior (and so N_M) cut to what a flight can observe, and the flight space."""
    space = flight_space(raster, clearance)
    return replace(raster, interior=space.observable), space
