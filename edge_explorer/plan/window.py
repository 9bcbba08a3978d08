"""A planning hierarchy whose cost per step does not grow with the building: a local planner on a window of the
maps that follows the vehicle, and a global route beyond it (issue #55).

Every planner of the registry (:mod:`edge_explorer.plan.registry`) flies inside :class:`WindowedPlanner`. On maps
that fit in the window (``size_m`` along both axes: the paper's 21 × 11 m buildings and every generated plan) it
hands the maps to its planner unchanged, so the planner flies exactly as it did without it. On larger maps:

* **Local layer.** The planner sees a ``size_m`` square crop of the observed maps (and of the fused map) around the
  vehicle, a copy on its own grid, so building its free space, graph and goals costs the same on a 270 m floor as on a
  30 m one. The window stays put until the vehicle is ``recentre_m`` from where the window would centre it, or the
  window it would take reaches a border of the map that the one in use stops short of (:func:`reaches_border`: near the
  border the centred window is shifted onto the map, and the strip beyond the window's edge, the building's outer wall
  in it, was out of the follower's sight); it then moves, and the planner's memory on the grid (dropped and committed
  targets, :meth:`GoalPlanner.memory`) is kept on the whole map and handed back cropped to the new window, and so is its
  goal while its target lies in the new window (a planner that replanned after every move could turn to a nearer target
  each time and fly back and forth between two windows: a generated test floor ran to the step cap that way). A move
  that would leave the goal's target just outside is shifted the least that keeps it in (:func:`keep_in_window`), as
  long as the vehicle stays as far inside as the recentring rule lets it drift (``size_m / 2 − recentre_m``): a path
  that leads away from its target first (round a wall) took the window with it, lost the goal at the edge, and the
  nearest frontier then lay the other way round the same wall (Nearest Frontier looped that way on a generated test
  floor for 5,000 steps). Where that margin cannot hold the target, the vehicle may come as near the edge as
  ``keep_margin_m`` (a learned flight lost a goal 16 m round a wall that way, and went back and forth round it for 8,000
  steps on a generated val floor).
* **Global layer.** When the planner has nothing left in its window, the route layer (:mod:`edge_explorer.plan.
  route`) finds the nearest target the planner would explore (:meth:`GoalPlanner.targets`: the observed frontier,
  or the fused one for the predictive planners but the learned one on a whole floor) outside the window along the
  observed 0.20 m map. The vehicle flies towards it through the window (:class:`Transit`: the window's fine graph
  and the shared follower, to the last route point before the route leaves the window), and each time the window
  moves the local planner looks first: the route ends as soon as there is something to explore in the window. The
  transit's point only ever moves on along the route (a window that moved back and forth would otherwise send the
  vehicle back and forth with it); once the window holds no point of the route after it, the route ends and a new
  one starts from the vehicle. A target is dropped for the flight when its route's end is reached without the local
  planner taking it, when the fine graph cannot follow its route three times in a row, or when it was routed to
  four times (each progress rule is bounded, so the flight always ends).

The flight ends when neither layer has a target left.

**Whole-floor settings.** Once the observed cells span more than ``whole_floor_m`` (the 23 × 13 m envelope of
the buildings the planners were tuned on; the flight's own evidence, never the plan), the local planner is told so
(:meth:`GoalPlanner.on_whole_floor`) and takes its whole-floor settings for the rest of the flight; no building
that fits the envelope can trigger it.

**Maps that grow** (the daemon's, :mod:`edge_explorer.mapping.growing`) change their grid now and then, whether they
fit the window or not: the planner's memory on the grid moves with it (cells keep their place in metres), its goal,
whose target cells are indices on the old grid, is forgotten (it replans), and a route ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, GoalPlanner, PlannerConfig, View, nearest_frontier_goal
from edge_explorer.plan.route import Route, RouteConfig, nearest_route, via_index
from edge_explorer.predict.thresholding import ENVELOPE_M, observed_extent_m
from edge_explorer.vehicle.dynamics import Action, ActionTable
from edge_explorer.world.grid import UNKNOWN, GridSpec

_TRANSIT_TRIES = 3  # routes the fine graph could not follow in a row before their target is dropped
_ROUTES_PER_TARGET = 4  # routes to the same target cells before they are dropped (the local planner took over, the
# window moved, the global layer routed there again: a loop that would never end); a target the local planner had in
# its window and declined when a new route was chosen counts one too (:meth:`WindowedPlanner._new_route`)


@dataclass(frozen=True)
class WindowConfig:
    """The local window and the global route of :class:`WindowedPlanner`."""

    size_m: float = 24.0  # side of the square of the maps the local planner sees
    recentre_m: float = 4.0  # the window moves when the vehicle is this far from where it would centre it
    transit_margin_m: float = 2.0  # a route is followed to its last point this far inside the window's edge
    # the least distance the vehicle keeps from the window's edge when a move must keep the flown goal's target in
    # the window (``keep_in_window``) and the usual size_m / 2 − recentre_m cannot: a path that leads round a wall
    # 16 m from its target otherwise lost the goal at the move, the window emptied, and the global layer and the
    # local planner sent the vehicle back and forth round that wall for 8,000 steps (a generated val floor)
    keep_margin_m: float = 3.0
    route: RouteConfig = RouteConfig()
    # when neither layer has a target left but the loop breakers dropped frontier still on the observed map, the drops
    # are forgiven this many times a flight before it ends (the learned planner with a 5 m goal choice ended 2 of the
    # 32 test floors with every frontier cell left dropped, 1,601 and 736 m² reachable, session 61)
    forgive_drops: int = 2
    # (long, short) sides: once the observed cells span more, the building is larger than any the planners were
    # tuned on (the predictor's 21 × 11 m envelope + 2 m) and the local planner takes its whole-floor settings
    whole_floor_m: tuple[float, float] = ENVELOPE_M

    def __post_init__(self) -> None:
        if self.size_m <= 0 or not 0 < self.recentre_m < self.size_m / 2:
            raise ValueError("size_m must be positive and recentre_m in (0, size_m / 2)")
        if not 0 <= self.transit_margin_m < self.size_m / 2 - self.recentre_m:
            raise ValueError("transit_margin_m must be in [0, size_m / 2 − recentre_m)")
        if not 0 < self.keep_margin_m <= self.size_m / 2 - self.recentre_m:
            raise ValueError("keep_margin_m must be in (0, size_m / 2 − recentre_m]")


@dataclass(frozen=True)
class Window:
    """A crop of the 0.20 m map: its first cell and its shape, in cells of the whole map."""

    row0: int
    col0: int
    shape: tuple[int, int]

    def slices(self, factor: int = 1) -> tuple[slice, slice]:
        """The crop's rows and columns on a map ``factor``× finer than the 0.20 m one."""
        return (
            slice(self.row0 * factor, (self.row0 + self.shape[0]) * factor),
            slice(self.col0 * factor, (self.col0 + self.shape[1]) * factor),
        )

    def grid(self, whole: GridSpec) -> GridSpec:
        """The crop's own grid: ``whole``'s resolution, origin at the crop's first cell."""
        x0, y0 = whole.origin_xy
        r = whole.resolution_m
        return GridSpec((x0 + self.col0 * r, y0 + self.row0 * r), r, self.shape)


def place_window(low_grid: GridSpec, pose_xy_m: tuple[float, float], size_m: float) -> Window:
    """The window of side ``size_m`` (at most the map) centred on the vehicle, shifted to lie on the map."""
    cells = max(int(round(size_m / low_grid.resolution_m)), 1)
    rows, cols = min(cells, low_grid.shape[0]), min(cells, low_grid.shape[1])
    row, col = (int(v) for v in low_grid.cell_of(*pose_xy_m))
    row0 = int(np.clip(row - rows // 2, 0, low_grid.shape[0] - rows))
    col0 = int(np.clip(col - cols // 2, 0, low_grid.shape[1] - cols))
    return Window(row0, col0, (rows, cols))


def known_window(maps: ObservedMaps, keep_xy_m: tuple[tuple[float, float], ...], margin_m: float) -> Window:
    """The least crop of the 0.20 m map that holds every known cell of ``maps`` (on either grid) and the points
    ``keep_xy_m``, grown by ``margin_m`` and clipped to the map. A search that crosses only known cells, and measures
    its free space at most ``margin_m`` beyond them, finds on this crop what it finds on the whole map, at the cost
    of the known part only: the maps of a flight grow ahead of the vehicle, so on a whole floor a third or more of
    them is unknown slack (the daemon's way home, :mod:`edge_explorer.runtime.daemon.phases`)."""
    grid, factor = maps.low_grid, maps.factor
    high_known, low_known = maps.high != UNKNOWN, maps.low != UNKNOWN
    points = np.array([grid.cell_of(*xy) for xy in keep_xy_m], dtype=np.int64).reshape(-1, 2)
    points = np.clip(points, 0, np.array(grid.shape) - 1)
    rows = np.concatenate(
        [np.flatnonzero(high_known.any(axis=1)) // factor, np.flatnonzero(low_known.any(axis=1)), points[:, 0]]
    )
    cols = np.concatenate(
        [np.flatnonzero(high_known.any(axis=0)) // factor, np.flatnonzero(low_known.any(axis=0)), points[:, 1]]
    )
    if not rows.size:
        return Window(0, 0, grid.shape)
    grow = int(math.ceil(margin_m / grid.resolution_m))
    row0, col0 = max(int(rows.min()) - grow, 0), max(int(cols.min()) - grow, 0)
    row1, col1 = min(int(rows.max()) + grow + 1, grid.shape[0]), min(int(cols.max()) + grow + 1, grid.shape[1])
    return Window(row0, col0, (row1 - row0, col1 - col0))


def reaches_border(wanted: Window, window: Window, grid: GridSpec) -> bool:
    """Whether ``wanted`` reaches a border of the map ``grid`` that ``window`` stops short of. Near the map's border
    the centred window is shifted onto the map, so it may lie less than ``recentre_m`` from the one in use while the
    vehicle is far off that one's centre: then the strip of map between the window and the border, walls included,
    was out of the follower's sight (a vehicle 0.2 m from the window's edge brushed the building's outer wall just
    beyond it, 4 times, on a generated val floor)."""
    for start, size, n, old_start in (
        (wanted.row0, wanted.shape[0], grid.shape[0], window.row0),
        (wanted.col0, wanted.shape[1], grid.shape[1], window.col0),
    ):
        if (start == 0 and old_start > 0) or (start + size == n and old_start + size < n):
            return True
    return False


def keep_in_window(
    window: Window,
    shape: tuple[int, int],
    keep: np.ndarray,
    vehicle: tuple[int, int],
    margin: int,
    least_margin: int | None = None,
) -> Window:
    """``window`` shifted the least along each axis so that the cells ``keep`` (flat indices on a map of ``shape``)
    and their neighbours lie in it (a frontier target on the window's edge would lose the unknown neighbour that
    makes it one) while the ``vehicle``'s cell stays ``margin`` cells inside its edges and the window on the map. Where
    ``margin`` is too much for that, the vehicle may come as near the edge as ``least_margin`` cells (default
    ``margin``), keeping as much margin as it can; ``window`` is unchanged along an axis where even that cannot be
    done."""
    rows, cols = np.divmod(np.asarray(keep, dtype=np.int64), shape[1])
    rows = np.clip([rows.min() - 1, rows.max() + 1], 0, shape[0] - 1)
    cols = np.clip([cols.min() - 1, cols.max() + 1], 0, shape[1] - 1)
    least = margin if least_margin is None else min(least_margin, margin)
    starts = []
    for start, size, n, lo, hi, at in (
        (window.row0, window.shape[0], shape[0], rows.min(), rows.max(), vehicle[0]),
        (window.col0, window.shape[1], shape[1], cols.min(), cols.max(), vehicle[1]),
    ):
        chosen = start
        for m in range(margin, least - 1, -1):
            first = max(int(hi) - size + 1, at + m - size + 1, 0)  # the lowest start that holds both, on the map
            last = min(int(lo), at - m, n - size)  # the highest
            if first <= last:
                chosen = int(np.clip(start, first, last))
                break
        starts.append(chosen)
    return Window(starts[0], starts[1], window.shape)


def crop_maps(maps: ObservedMaps, window: Window) -> ObservedMaps:
    """A copy of ``maps`` within ``window`` (0.20 m cells), on the crop's own grids."""
    high = np.ascontiguousarray(maps.high[window.slices(maps.factor)])
    low = np.ascontiguousarray(maps.low[window.slices()])
    low_grid = window.grid(maps.low_grid)
    high_grid = GridSpec(low_grid.origin_xy, maps.high_grid.resolution_m, high.shape)
    return ObservedMaps(high_grid, low_grid, high, low, maps.fusion)


def moved_mask(mask: np.ndarray, old: GridSpec, new: GridSpec) -> np.ndarray:
    """``mask`` (on ``old``) on ``new``, a grid of the same resolution whose cells line up with ``old``'s: the
    overlap is copied, the rest is zero (False)."""
    out = np.zeros(new.shape, dtype=mask.dtype)
    dr = int(round((old.origin_xy[1] - new.origin_xy[1]) / new.resolution_m))
    dc = int(round((old.origin_xy[0] - new.origin_xy[0]) / new.resolution_m))
    r0, c0 = max(dr, 0), max(dc, 0)
    r1, c1 = min(dr + mask.shape[0], new.shape[0]), min(dc + mask.shape[1], new.shape[1])
    if r0 < r1 and c0 < c1:
        out[r0:r1, c0:c1] = mask[r0 - dr : r1 - dr, c0 - dc : c1 - dc]
    return out


class Transit(GoalPlanner):
    """Flies the vehicle to a point of a global route inside the window (:attr:`via_xy_m`) along the window's fine
    graph with the shared follower; answers ``None`` (no spin) when it cannot get there or has arrived.

    It flies to a graph node within ``reach_m`` of the point; a route point keeps more than that from every wall it
    knows (:attr:`RouteConfig.min_clearance_m`), so the node lies on the route's side of any wall near it (with a
    looser reach the vehicle flew to the far side of a thin wall, and back when the window moved)."""

    def __init__(self, config: PlannerConfig, table: ActionTable | None, reach_m: float) -> None:
        super().__init__(config, table)
        self.reach_m = reach_m
        self.via_xy_m: np.ndarray | None = None
        self.arrived = False

    def reset(self) -> None:
        super().reset()
        self.via_xy_m, self.arrived = None, False

    def lead_to(self, via_xy_m: np.ndarray) -> None:
        """Fly to ``via_xy_m`` from now on (a new goal at the next step)."""
        self.via_xy_m, self.arrived = np.asarray(via_xy_m, dtype=float), False
        self.remember({})

    def view(self, maps: ObservedMaps, pose: Pose, fused_low: np.ndarray | None = None) -> View:
        target = np.zeros(maps.low.shape, dtype=bool)
        if self.via_xy_m is not None and not self.arrived:
            row, col = maps.low_grid.cell_of(*self.via_xy_m)
            if maps.low_grid.contains(row, col):
                target[int(row), int(col)] = True
        return View(maps, pose, target, self.config, self._free)

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if not view.frontier.any():
            return None
        return nearest_frontier_goal(view, pose, view.frontier, self.reach_m)

    def status(self, goal: Goal, view: View, pose: Pose) -> str:
        if not view.traversable.contains_path(goal.path_xy_m):
            return "replan"
        return super().status(goal, view, pose)

    def on_failure(self, goal: Goal, view: View, pose: Pose) -> Goal | None:
        self.arrived = True  # reached (or stuck on the way): the window decides what comes next
        return None

    def _spin(self, view: View, pose: Pose, previous_action: int) -> int | None:
        return None


class WindowedPlanner:
    """The planning hierarchy (module docstring) around one registry planner (:attr:`local`)."""

    def __init__(self, local: GoalPlanner, config: WindowConfig = WindowConfig()) -> None:
        self.local = local
        self.config = config
        self.transit = Transit(local.config, local.table, 0.9 * config.route.min_clearance_m)
        self.reset()

    def reset(self) -> None:
        self.local.reset()
        self.transit.reset()
        self.window: Window | None = None
        self._fit_grid: GridSpec | None = None  # the 0.20 m grid of the last maps the local planner saw whole
        self._grid: GridSpec | None = None  # the whole 0.20 m map's grid the memory below lies on
        self._memory: dict[str, np.ndarray] = {}  # the local planner's memory on the whole map
        self._dropped: np.ndarray | None = None  # targets the global layer gave up on (bool, whole map)
        self._routed: np.ndarray | None = None  # how often each cell was a route's target (uint8, whole map)
        self.route: Route | None = None
        self.whole_floor = False  # the observed cells have spanned more than ``whole_floor_m`` this flight
        self._via = -1  # the index along the route of the transit's point
        self._failed_routes = 0
        self.routes = 0  # global decisions this flight
        self.forgiven = 0  # times this flight the drops were forgiven (``WindowConfig.forgive_drops``)

    def __getattr__(self, name: str) -> object:
        # what the local planner shows (fused, replans, last_action, predictive, …) reads through the hierarchy
        if name == "local":
            raise AttributeError(name)
        return getattr(self.local, name)

    def fits(self, maps: ObservedMaps) -> bool:
        """Whether the maps fit in the window, so the local planner sees them whole."""
        width_m, height_m = maps.low_grid.size_xy_m
        return max(width_m, height_m) <= self.config.size_m + 1e-9

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None:
        if not self.whole_floor:
            long_m, short_m = observed_extent_m(maps.low, maps.low_grid.resolution_m)
            if long_m > self.config.whole_floor_m[0] or short_m > self.config.whole_floor_m[1]:
                self.whole_floor = True
                self.local.on_whole_floor()
        if self.fits(maps) and self.window is None:
            if self._fit_grid is not None and self._fit_grid != maps.low_grid:  # maps that grew and still fit
                self.local.remember(self._whole_memory(maps.low_grid))
            self._fit_grid = maps.low_grid
            return self.local.act(maps, pose, previous_action, fused_low)
        moved = self._follow(maps, pose)
        if self.route is None or moved:
            action = self._local_act(maps, pose, previous_action, fused_low, moved)
            if action is not None:
                self.route, self._failed_routes = None, 0
                return action
            if not self._route_live(maps, fused_low) and not self._new_route(maps, pose, fused_low):
                return self._act_forgiven(maps, pose, previous_action, fused_low)
        for _ in range(_TRANSIT_TRIES):
            assert self.window is not None
            crop = crop_maps(maps, self.window)
            fused_crop = None if fused_low is None else np.ascontiguousarray(fused_low[self.window.slices()])
            action = self.transit.act(crop, pose, previous_action, fused_crop)
            if action is not None:
                return action
            via = self._via
            if self._follow(maps, pose, force=True):  # arrived off-centre: the window centres, the local planner looks
                action = self._local_act(maps, pose, previous_action, fused_low, True)
                if action is not None:
                    self.route, self._failed_routes = None, 0
                    return action
                if self._via > via:
                    continue  # on along the route from the centred window
            if not self._route_failed(maps, pose, fused_low):
                return self._act_forgiven(maps, pose, previous_action, fused_low)
        # routes are left but none was flown this step: hover and try the newest next step. Ending the flight here
        # stopped a learned flight at 75 % coverage with 815 m² reachable (floor-test-00022, session 55); each failure
        # counts towards dropping its target, so this still ends.
        return Action.HOVER

    def _act_forgiven(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None
    ) -> int | None:
        """``None`` (the flight is over), unless the drops are forgiven (:meth:`_forgive`): then the step is planned
        again."""
        if not self._forgive(maps, fused_low):
            return None
        return self.act(maps, pose, previous_action, fused_low)

    def _forgive(self, maps: ObservedMaps, fused_low: np.ndarray | None) -> bool:
        """Give back every target either layer dropped, at most ``forgive_drops`` times a flight, when some of them
        are still on the planner's frontier; whether it did. The loop breakers drop targets to end loops, and a
        flight that ends with reachable frontier dropped leaves the building unexplored."""
        if self.window is None or self._dropped is None or self._routed is None:
            return False
        if self.forgiven >= self.config.forgive_drops:
            return False
        self._park()
        dropped = self._dropped | self._memory.get("dropped", np.zeros_like(self._dropped))
        if not (self.local.targets(maps.low, fused_low) & dropped).any():
            return False
        self.forgiven += 1
        self._dropped[...] = False
        self._routed[...] = 0
        if "dropped" in self._memory:
            self._memory["dropped"][...] = False
        self.local.remember({k: np.ascontiguousarray(v[self.window.slices()]) for k, v in self._memory.items()})
        self.route, self._failed_routes = None, 0
        return True

    def _local_act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None, centred: bool
    ) -> int | None:
        """The local planner's action on the window; when it has nothing left and the window is not ``centred`` on
        the vehicle, the window centres and it looks again (what it missed may lie just beyond the old window)."""
        for _ in range(2):
            assert self.window is not None
            crop = crop_maps(maps, self.window)
            fused_crop = None if fused_low is None else np.ascontiguousarray(fused_low[self.window.slices()])
            action = self.local.act(crop, pose, previous_action, fused_crop)
            if action is not None or centred or not self._follow(maps, pose, force=True):
                return action
            centred = True
        return None

    def _follow(self, maps: ObservedMaps, pose: Pose, force: bool = False) -> bool:
        """Keep the window on the vehicle (module docstring; ``force``: centre it now); whether it moved. The memory
        moves with it."""
        grid = maps.low_grid
        if self._grid is None:  # the maps outgrew the window: what the planner remembered of them whole carries on
            self._memory = self._whole_memory(grid)
            self._grid = grid
        elif self._grid != grid:  # maps that grew: the whole-map memory follows the new grid, the route ends
            self._park()
            self._memory = {k: moved_mask(v, self._grid, grid) for k, v in self._memory.items()}
            if self._dropped is not None and self._routed is not None:
                self._dropped = moved_mask(self._dropped, self._grid, grid)
                self._routed = moved_mask(self._routed, self._grid, grid)
            self._grid, self.window, self.route = grid, None, None
        if self._dropped is None or self._routed is None:
            self._dropped = np.zeros(grid.shape, dtype=bool)
            self._routed = np.zeros(grid.shape, dtype=np.uint8)
        wanted = place_window(grid, pose[:2], self.config.size_m)
        goal = None
        if self.window is not None:
            shift = max(abs(wanted.row0 - self.window.row0), abs(wanted.col0 - self.window.col0))
            near = shift * grid.resolution_m < self.config.recentre_m and not reaches_border(wanted, self.window, grid)
            if wanted == self.window or (not force and near):
                return False
            carried = self.local.goal_on(self.window.grid(grid), grid)
            if carried is not None and not force:  # the move keeps the goal's target in view (module docstring)
                margin = int(round((self.config.size_m / 2 - self.config.recentre_m) / grid.resolution_m))
                least = int(round(self.config.keep_margin_m / grid.resolution_m))
                vehicle = tuple(int(v) for v in grid.cell_of(*pose[:2]))
                wanted = keep_in_window(wanted, grid.shape, carried.target_cells, vehicle, margin, least)
                if wanted == self.window:
                    return False
            self._park()
            goal = self.local.goal_on(self.window.grid(grid), wanted.grid(grid))
        self.window = wanted
        memory = {k: np.ascontiguousarray(v[wanted.slices()]) for k, v in self._memory.items()}
        self.local.remember(memory, goal)
        self.transit.remember({})
        if self.route is not None and not self._lead(self.route, onward_only=True):
            self.route = None
        return True

    def _whole_memory(self, grid: GridSpec) -> dict[str, np.ndarray]:
        """The local planner's memory of the maps it saw whole (on :attr:`_fit_grid`), moved onto ``grid`` (maps
        that grew keep their cells where they were in metres)."""
        old = self._fit_grid
        if old is None:
            return {}
        return {k: moved_mask(v, old, grid) for k, v in self.local.memory().items() if v.shape == old.shape}

    def _park(self) -> None:
        """Write the local planner's memory (on the current window) into the whole-map memory."""
        assert self._grid is not None
        if self.window is None:
            return
        for key, mask in self.local.memory().items():
            if mask.shape != self.window.shape:
                continue  # made on maps that fit whole, before the hierarchy took over
            whole = self._memory.setdefault(key, np.zeros(self._grid.shape, dtype=bool))
            whole[self.window.slices()] = mask

    def _inner(self) -> tuple[slice, slice]:
        """The window's rows and columns on the whole map less the transit margin on each side that does not lie
        on the map's border (nothing lies beyond the border to be led to)."""
        assert self.window is not None and self._grid is not None
        m = int(math.ceil(self.config.transit_margin_m / self._grid.resolution_m))
        (rows, cols), (n_rows, n_cols) = self.window.slices(), self._grid.shape
        return (
            slice(rows.start + (m if rows.start > 0 else 0), rows.stop - (m if rows.stop < n_rows else 0)),
            slice(cols.start + (m if cols.start > 0 else 0), cols.stop - (m if cols.stop < n_cols else 0)),
        )

    def _inside(self) -> np.ndarray:
        """bool on the whole map: the window's inner part (:meth:`_inner`), the targets the local planner had in
        view."""
        assert self._grid is not None
        inside = np.zeros(self._grid.shape, dtype=bool)
        inside[self._inner()] = True
        return inside

    def _targets(self, maps: ObservedMaps, fused_low: np.ndarray | None) -> np.ndarray:
        """bool on the whole map: what the local planner would explore, less what either layer dropped."""
        self._park()
        assert self._dropped is not None
        dropped = self._dropped | self._memory.get("dropped", np.zeros_like(self._dropped))
        return self.local.targets(maps.low, fused_low) & ~dropped

    def _route_live(self, maps: ObservedMaps, fused_low: np.ndarray | None) -> bool:
        """Whether there is a route and its target is still there to explore."""
        return self.route is not None and bool(self._targets(maps, fused_low).flat[self.route.target_cells].any())

    def _new_route(self, maps: ObservedMaps, pose: Pose, fused_low: np.ndarray | None) -> bool:
        """Route to the nearest target outside the window; whether there is one.

        The targets inside the window were in the local planner's view and it did not take them: each counts as one
        route to it. Otherwise a target the local planner declines is routed to again as soon as the window has
        left it, and two such targets far apart take the vehicle back and forth between them: a learned flight on a
        real whole floor flew about 700 m at 94.3 % coverage that way, one target pair after another (session 59)."""
        assert self._routed is not None
        inside = self._inside()
        targets = self._targets(maps, fused_low)
        declined = np.flatnonzero(targets & inside)
        if declined.size:
            self._routed.flat[declined] = np.minimum(self._routed.flat[declined], 254) + 1
            targets &= ~self._drop(declined[self._routed.flat[declined] > _ROUTES_PER_TARGET])
        targets &= ~inside
        while True:
            self.routes += 1
            self.route = nearest_route(maps.low, maps.low_grid, targets, pose[:2], self.config.route)
            if self.route is None:
                return False
            cells = self.route.target_cells
            self._routed.flat[cells] = np.minimum(self._routed.flat[cells], 254) + 1
            if self._routed.flat[cells].max() <= _ROUTES_PER_TARGET:
                break
            targets &= ~self._drop(cells)
        self._lead(self.route)
        return True

    def _lead(self, route: Route, onward_only: bool = False) -> bool:
        """Point the transit at the last point of ``route`` before it leaves the window (less the margin); whether
        the route still leads anywhere. With ``onward_only`` (the window moved) the point only moves on: it stays
        while it lies in the window and that last point is no further along; when it has left the window it moves to
        the last point of the route's next stretch in the window *after* it, and the route has ended (False) when
        no point after it lies in the window (the vehicle was led off the route: a new route starts from where it
        is, and each counts against :data:`_ROUTES_PER_TARGET`). Going back to the start of the route instead, as
        a route whose start the window had left once did, flew the vehicle back and forth between the two ends
        for thousands of steps (a generated test floor, session 46)."""
        assert self._grid is not None
        rows, cols = self._inner()
        (x0, y0), r = self._grid.origin_xy, self._grid.resolution_m
        box = (x0 + cols.start * r, y0 + rows.start * r, x0 + cols.stop * r, y0 + rows.stop * r)
        path = route.path_xy_m
        via = via_index(path, box)
        if onward_only and 0 <= self._via < len(path):
            x, y = path[:, 0], path[:, 1]
            inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
            if inside[self._via]:
                if via <= self._via:
                    return True  # the transit's point is still in the window and no further along: it stays
            else:
                onward = np.flatnonzero(inside[self._via + 1 :])
                if len(onward) == 0:
                    return False
                start = self._via + 1 + int(onward[0])
                via = start + via_index(path[start:], box)
        self._via = via
        self.transit.lead_to(path[via])
        return True

    def _drop(self, cells: np.ndarray) -> np.ndarray:
        """Drop the target ``cells`` (flat indices on the whole map) and the cells within two of them for the
        flight; the mask of what was dropped."""
        assert self._dropped is not None
        targets = np.zeros(self._dropped.shape, dtype=np.uint8)
        targets.flat[cells] = 1
        dropped = cv2.dilate(targets, np.ones((5, 5), np.uint8)).astype(bool)
        self._dropped |= dropped
        return dropped

    def _route_failed(self, maps: ObservedMaps, pose: Pose, fused_low: np.ndarray | None) -> bool:
        """The transit reached its point or could not: drop the route's target when that was the route's end (the
        local planner did not take it) or after :data:`_TRANSIT_TRIES` failures; then route anew (also when the
        window moved past the route's last point, :meth:`_lead`). Whether a new route exists."""
        if self.route is None:
            return self._new_route(maps, pose, fused_low)
        self._failed_routes += 1
        if self._via == len(self.route.path_xy_m) - 1 or self._failed_routes >= _TRANSIT_TRIES:
            self._drop(self.route.target_cells)
            self._failed_routes = 0
        return self._new_route(maps, pose, fused_low)
