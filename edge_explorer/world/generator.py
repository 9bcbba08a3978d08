"""Procedural office floor plans that match the paper's training dataset (docs/design.md §4).

``generate_plan(seed, name, style)`` draws one building inside the 21 m × 11 m envelope: axis-aligned walls of
0.10–0.20 m, open doors of 0.80–1.20 m, rooms mostly on the perimeter (internal rooms in the ``internal`` style),
L/U-shaped or corner-cut perimeters, tall furniture (shelves, cabinets: part of the 2-D plan) and low furniture
(tables, desks, beds: 3-D only). Every returned plan passes :func:`validate_plan` and is connected at the robot's
radius when rasterized at 0.05 m; the check is part of generation, so a caller never sees a bad plan.

How a plan is made (all lengths are integer multiples of :data:`UNIT_M` = 0.05 m, so every coordinate is snapped):

1. A *layout* (:mod:`edge_explorer.world.layouts`): rectangles labelled as rooms, corridors (one label may be
   several rectangles, e.g. a corridor loop) or a hall, tiling a footprint that is a rectangle, an L, a U or a
   rectangle with a corner cut away.
2. The layout is painted on a coordinate-compressed label grid (one cell per distinct x/y interval, a few dozen
   cells), which makes the geometry exact and fast: the outline is traced on it, boundaries between two labels
   become interior walls centred on the boundary, the footprint's outline becomes perimeter walls lying inside it.
3. Doors: a spanning tree of the room adjacency graph grown from the corridor/hall (hub edges preferred), plus a
   few extra doors that make loops. Every room gets at least one door; a door is a box across its wall's
   thickness, at least ``wall thickness + 0.1 m`` away from the walls it meets.
4. Furniture per room, kept out of a 0.8 m zone in front of each door; tall items stand against walls, at least
   0.6 m from each other, so they cannot close a passage.
5. A random symmetry of the rectangle (rotation / mirror) so all orientations occur; then validation and the
   robot-radius connectivity check. A failed attempt is retried with a derived seed; :class:`PlanError` after
   :data:`MAX_ATTEMPTS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from edge_explorer.errors import PlanError
from edge_explorer.world.grid import HIGH_RES_M
from edge_explorer.world.layouts import STYLE_FUNCS, UNIT_M, Box, Layout, Retry, uniform_u
from edge_explorer.world.plan import MIN_DOOR_WIDTH_M, FloorPlan, Furniture, Rect, validate_plan
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, check_connected, rasterize

STYLES: tuple[str, ...] = ("corridor", "hall", "lshape", "internal")
GENERATOR_VERSION = 1  # bump whenever the same (seed, style) would give a different plan
MAX_ATTEMPTS = 6

MIN_ROOMS, MAX_ROOMS = 3, 14
_MIN_DOOR_U = int(round(MIN_DOOR_WIDTH_M / UNIT_M))  # 16
_MAX_DOOR_U = 24  # 1.20 m
_DOOR_KEEPOUT_U = 16  # furniture stays 0.8 m clear of each door, on both sides
_TALL_GAP_U = 12  # tall items keep 0.6 m from each other (a robot of 0.5 m passes between them)


def _m(units: int) -> float:
    return round(units * UNIT_M, 2)


# ---------------------------------------------------------------------------------------------------------------
# Geometry: label grid → outline, walls, adjacency
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Segment:
    """A stretch of boundary between two labels on one grid line, with the clearance each end needs."""

    vertical: bool  # the boundary line is x = line (else y = line)
    line: int
    s0: int
    s1: int
    margin0: int
    margin1: int

    @property
    def usable(self) -> int:
        return self.s1 - self.s0 - self.margin0 - self.margin1


@dataclass
class _Geometry:
    outline: list[tuple[int, int]]
    walls: list[Box]
    segments: dict[tuple[int, int], list[_Segment]]  # (label_a, label_b), a < b → shared boundary stretches
    room_boxes: dict[int, Box]  # free interior (inside the walls) of every single-rectangle region


def _label_grid(lay: Layout) -> tuple[list[int], list[int], np.ndarray]:
    xs = sorted({v for _, (x0, _, x1, _) in lay.rects for v in (x0, x1)} | {0, lay.w})
    ys = sorted({v for _, (_, y0, _, y1) in lay.rects for v in (y0, y1)} | {0, lay.h})
    xi = {v: k for k, v in enumerate(xs)}
    yi = {v: k for k, v in enumerate(ys)}
    grid = np.zeros((len(ys) - 1, len(xs) - 1), dtype=np.int32)
    for label, (x0, y0, x1, y1) in lay.rects:
        grid[yi[y0] : yi[y1], xi[x0] : xi[x1]] = label
    return xs, ys, grid


def _trace_outline(xs: list[int], ys: list[int], inside: np.ndarray) -> list[tuple[int, int]]:
    """Counter-clockwise outline of the footprint on the compressed grid, collinear vertices merged."""
    ny, nx = inside.shape
    pad = np.zeros((ny + 2, nx + 2), dtype=bool)
    pad[1:-1, 1:-1] = inside
    nxt: dict[tuple[int, int], tuple[int, int]] = {}
    # directed edges with the inside on the left; vertices are (col, row) indices into xs, ys
    for i, j in zip(*np.nonzero(inside), strict=True):
        i, j = int(i), int(j)
        if not pad[i, j + 1]:  # below
            nxt[(j, i)] = (j + 1, i)
        if not pad[i + 1, j + 2]:  # right
            nxt[(j + 1, i)] = (j + 1, i + 1)
        if not pad[i + 2, j + 1]:  # above
            nxt[(j + 1, i + 1)] = (j, i + 1)
        if not pad[i + 1, j]:  # left
            nxt[(j, i + 1)] = (j, i)
    start = min(nxt, key=lambda v: (v[1], v[0]))
    loop = [start]
    v = nxt[start]
    while v != start:
        loop.append(v)
        v = nxt[v]
        if len(loop) > len(nxt):
            raise Retry("footprint outline is not a single loop")
    if len(loop) != len(nxt):
        raise Retry("footprint has holes or touching corners")
    n = len(loop)
    corners = []
    for k in range(n):
        (ax, ay), (bx, by), (cx, cy) = loop[k - 1], loop[k], loop[(k + 1) % n]
        if (bx - ax) * (cy - by) - (by - ay) * (cx - bx) != 0:
            corners.append((xs[bx], ys[by]))
    return corners


def _perimeter_walls(outline: list[tuple[int, int]], t: int) -> list[Box]:
    """Boxes of thickness ``t`` inside a CCW orthogonal outline; reflex corners are filled by extending edges."""
    n = len(outline)
    walls = []
    for k in range(n):
        p, q = outline[k], outline[(k + 1) % n]
        dx, dy = int(np.sign(q[0] - p[0])), int(np.sign(q[1] - p[1]))

        def reflex(a: tuple[int, int], b: tuple[int, int], c: tuple[int, int]) -> bool:
            return (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]) < 0

        ext0 = t if reflex(outline[k - 1], p, q) else 0
        ext1 = t if reflex(p, q, outline[(k + 2) % n]) else 0
        a = (p[0] - dx * ext0, p[1] - dy * ext0)
        b = (q[0] + dx * ext1, q[1] + dy * ext1)
        nx, ny = -dy, dx  # inward normal (left of the direction of travel)
        c = (a[0] + nx * t, a[1] + ny * t)
        xs = (a[0], b[0], c[0])
        ys = (a[1], b[1], c[1])
        walls.append((min(xs), min(ys), max(xs), max(ys)))
    return walls


def _geometry(lay: Layout, t_int: int, t_ext: int) -> _Geometry:
    xs, ys, grid = _label_grid(lay)
    inside = grid > 0
    outline = _trace_outline(xs, ys, inside)
    walls = _perimeter_walls(outline, t_ext)
    lo, hi = t_int // 2, t_int - t_int // 2  # an interior wall on line v covers [v - lo, v + hi]
    segments: dict[tuple[int, int], list[_Segment]] = {}
    ny, nx = grid.shape
    g = grid.tolist()

    def scan(vertical: bool) -> None:
        n_lines, n_cells = (nx, ny) if vertical else (ny, nx)
        cuts = ys if vertical else xs  # coordinates along the line
        for k in range(1, n_lines):
            line = xs[k] if vertical else ys[k]

            def pair(i: int, k: int = k) -> tuple[int, int]:
                return (g[i][k - 1], g[i][k]) if vertical else (g[k - 1][i], g[k][i])

            def outline_end(i: int) -> bool:  # is cell row/col i (beyond a run end) outside the footprint?
                if i < 0 or i >= n_cells:
                    return True
                a, b = pair(i)
                return a == 0 or b == 0

            pairs = [pair(i) for i in range(n_cells)]
            wall = [a != b and a > 0 and b > 0 for a, b in pairs]
            i = 0
            while i < n_cells:
                if not wall[i]:
                    i += 1
                    continue
                j = i
                while j < n_cells and wall[j]:
                    j += 1
                # one wall box for the whole run, extended into the perpendicular walls it meets
                s0 = cuts[i] - (0 if outline_end(i - 1) else lo)
                s1 = cuts[j] + (0 if outline_end(j) else hi)
                walls.append((line - lo, s0, line + hi, s1) if vertical else (s0, line - lo, s1, line + hi))
                # door candidates: stretches with one pair of labels
                a = i
                while a < j:
                    b = a
                    while b < j and pairs[b] == pairs[a]:
                        b += 1
                    la, lb = pairs[a]
                    key = (la, lb) if la < lb else (lb, la)
                    m0 = (t_ext if outline_end(a - 1) else hi) + 2
                    m1 = (t_ext if outline_end(b) else lo) + 2
                    segments.setdefault(key, []).append(_Segment(vertical, line, cuts[a], cuts[b], m0, m1))
                    a = b
                i = j

    scan(True)
    scan(False)
    room_boxes = _free_boxes(lay, xs, ys, grid, lo, hi, t_ext)
    return _Geometry(outline, walls, segments, room_boxes)


def _free_boxes(
    lay: Layout, xs: list[int], ys: list[int], grid: np.ndarray, lo: int, hi: int, t_ext: int
) -> dict[int, Box]:
    """The free rectangle inside the walls of every region that is one rectangle (rooms, halls)."""
    count: dict[int, int] = {}
    for label, _ in lay.rects:
        count[label] = count.get(label, 0) + 1
    xi = {v: k for k, v in enumerate(xs)}
    yi = {v: k for k, v in enumerate(ys)}
    ny, nx = grid.shape
    out = {}
    for label, (x0, y0, x1, y1) in lay.rects:
        if count[label] != 1:
            continue
        i0, i1, j0, j1 = yi[y0], yi[y1], xi[x0], xi[x1]

        def outside(cells: np.ndarray) -> bool:
            return cells.size == 0 or bool((cells == 0).any())

        left = t_ext if j0 == 0 or outside(grid[i0:i1, j0 - 1]) else hi
        right = t_ext if j1 == nx or outside(grid[i0:i1, j1]) else lo
        bottom = t_ext if i0 == 0 or outside(grid[i0 - 1, j0:j1]) else hi
        top = t_ext if i1 == ny or outside(grid[i1, j0:j1]) else lo
        out[label] = (x0 + left, y0 + bottom, x1 - right, y1 - top)
    return out


# ---------------------------------------------------------------------------------------------------------------
# Doors and furniture
# ---------------------------------------------------------------------------------------------------------------
def _door_on(rng: np.random.Generator, seg: _Segment, t_int: int) -> Box:
    width = int(rng.integers(_MIN_DOOR_U, min(_MAX_DOOR_U, seg.usable) + 1))
    lo_pos, hi_pos = seg.s0 + seg.margin0, seg.s1 - seg.margin1 - width
    r = rng.random()
    if r < 0.3:
        pos = lo_pos  # next to a corner, as most office doors are
    elif r < 0.6:
        pos = hi_pos
    else:
        pos = int(rng.integers(lo_pos, hi_pos + 1))
    lo, hi = t_int // 2, t_int - t_int // 2
    if seg.vertical:
        return (seg.line - lo, pos, seg.line + hi, pos + width)
    return (pos, seg.line - lo, pos + width, seg.line + hi)


def _place_doors(
    rng: np.random.Generator, lay: Layout, geo: _Geometry, t_int: int, closed: frozenset[int] = frozenset()
) -> tuple[list[Box], dict[int, list[Box]]]:
    """Spanning tree from the hub(s) over feasible adjacencies, then a few loop-making extra doors.

    Labels in ``closed`` (a whole floor's lift shafts) get no door and stay out of the tree."""
    feasible: dict[tuple[int, int], list[_Segment]] = {}
    for key, segs in geo.segments.items():
        ok = [s for s in segs if s.usable >= _MIN_DOOR_U]
        if ok and key[0] not in closed and key[1] not in closed:
            feasible[key] = ok
    labels = range(1, len(lay.kinds))
    hubs = [lb for lb in labels if lay.kinds[lb] in ("corridor", "hall")]
    in_tree = {hubs[0] if hubs else 1}
    chosen: list[tuple[int, int]] = []
    while len(in_tree) < len(lay.kinds) - 1 - len(closed):
        frontier = sorted(k for k in feasible if (k[0] in in_tree) != (k[1] in in_tree))
        if not frontier:
            raise Retry("a room has no wall long enough for a door to the rest of the building")
        from_hub = [k for k in frontier if (k[0] if k[0] in in_tree else k[1]) in hubs]
        pool = from_hub or frontier
        key = pool[int(rng.integers(len(pool)))]
        chosen.append(key)
        in_tree.update(key)
    p_extra = float(rng.uniform(0.0, 0.3))
    for key in sorted(feasible):
        if key not in chosen and rng.random() < (0.6 if (key[0] in hubs or key[1] in hubs) else p_extra):
            chosen.append(key)
    doors: list[Box] = []
    by_label: dict[int, list[Box]] = {lb: [] for lb in labels}
    for key in chosen:
        segs = feasible[key]
        seg = max(segs, key=lambda s: s.usable) if rng.random() < 0.7 else segs[int(rng.integers(len(segs)))]
        door = _door_on(rng, seg, t_int)
        doors.append(door)
        by_label[key[0]].append(door)
        by_label[key[1]].append(door)
    return doors, by_label


def _overlap(a: Box, b: Box, gap: int = 0) -> bool:
    return a[0] - gap < b[2] and b[0] - gap < a[2] and a[1] - gap < b[3] and b[1] - gap < a[3]


def _furnish(rng: np.random.Generator, box: Box, doors: list[Box], n_items: int) -> list[tuple[Box, float]]:
    """Up to ``n_items`` boxes in a room's free rectangle, out of the doors' keep-out zones."""
    x0, y0, x1, y1 = box
    keepout = [
        (d[0] - _DOOR_KEEPOUT_U, d[1] - _DOOR_KEEPOUT_U, d[2] + _DOOR_KEEPOUT_U, d[3] + _DOOR_KEEPOUT_U) for d in doors
    ]
    items: list[tuple[Box, float, bool]] = []
    for _ in range(2 * n_items):
        if len(items) >= n_items:
            break
        tall = rng.random() < 0.45
        against_wall = tall or rng.random() < 0.6
        if tall:
            depth, length = uniform_u(rng, 0.3, 0.6), uniform_u(rng, 0.6, 2.0)
            height = _m(uniform_u(rng, 1.6, 2.2))
        else:
            depth, length = uniform_u(rng, 0.6, 1.6), uniform_u(rng, 0.6, 2.0)
            height = _m(uniform_u(rng, 0.4, 1.2))
        side = int(rng.integers(4))
        along_x = side in (0, 1)  # against the bottom/top wall: long side along x
        wx, wy = (length, depth) if along_x else (depth, length)
        if wx > x1 - x0 or wy > y1 - y0:
            continue
        if against_wall:
            if along_x:
                fx0 = int(rng.integers(x0, x1 - wx + 1))
                fy0 = y0 if side == 0 else y1 - wy
            else:
                fy0 = int(rng.integers(y0, y1 - wy + 1))
                fx0 = x0 if side == 2 else x1 - wx
        else:  # free-standing: leave a 0.6 m passage to the walls
            m = _TALL_GAP_U
            if wx + 2 * m > x1 - x0 or wy + 2 * m > y1 - y0:
                continue
            fx0 = int(rng.integers(x0 + m, x1 - m - wx + 1))
            fy0 = int(rng.integers(y0 + m, y1 - m - wy + 1))
        cand = (fx0, fy0, fx0 + wx, fy0 + wy)
        if any(_overlap(cand, k) for k in keepout):
            continue
        if any(_overlap(cand, b, _TALL_GAP_U if (tall and t) else 0) for b, _, t in items):
            continue
        items.append((cand, height, tall))
    return [(b, hgt) for b, hgt, _ in items]


# ---------------------------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------------------------
def _symmetry(code: int, w: int, h: int) -> Callable[[int, int], tuple[int, int]]:
    """One of the 8 symmetries of the w × h rectangle, as a map of points in layout units."""

    def f(x: int, y: int) -> tuple[int, int]:
        if code & 2:
            x = w - x
        if code & 4:
            y = h - y
        return (y, x) if code & 1 else (x, y)

    return f


def _build(rng: np.random.Generator, style: str, seed: int, name: str) -> FloorPlan:
    lay = STYLE_FUNCS[style](rng)
    if not MIN_ROOMS <= lay.n_rooms <= MAX_ROOMS:
        raise Retry(f"{lay.n_rooms} rooms")
    t_int = int(rng.integers(2, 4))  # 0.10 or 0.15 m
    t_ext = int(rng.integers(3, 5))  # 0.15 or 0.20 m
    geo = _geometry(lay, t_int, t_ext)
    doors, doors_of = _place_doors(rng, lay, geo, t_int)
    furniture: list[tuple[Box, float]] = []
    for label, box in geo.room_boxes.items():
        kind = lay.kinds[label]
        area_m2 = (box[2] - box[0]) * (box[3] - box[1]) * UNIT_M**2
        cap = min(6, int(area_m2 / 2.5)) if kind == "room" else (min(6, int(area_m2 / 8)) if kind == "hall" else 0)
        if cap > 0:
            furniture += _furnish(rng, box, doors_of[label], int(rng.integers(0, cap + 1)))
    sym = _symmetry(int(rng.integers(8)), lay.w, lay.h)

    def to_rect(b: Box) -> Rect:
        (ax, ay), (bx, by) = sym(b[0], b[1]), sym(b[2], b[3])
        return Rect(_m(min(ax, bx)), _m(min(ay, by)), _m(max(ax, bx)), _m(max(ay, by)))

    pts = [sym(x, y) for x, y in geo.outline]
    area2 = sum(pts[k - 1][0] * pts[k][1] - pts[k][0] * pts[k - 1][1] for k in range(len(pts)))
    if area2 < 0:  # a mirror reversed the orientation: keep the outline counter-clockwise
        pts.reverse()
    k0 = min(range(len(pts)), key=lambda k: (pts[k][1], pts[k][0]))
    outline = tuple((_m(x), _m(y)) for x, y in pts[k0:] + pts[:k0])
    return FloorPlan(
        name=name,
        outline=outline,
        walls=tuple(to_rect(b) for b in geo.walls),
        doors=tuple(to_rect(b) for b in doors),
        furniture=tuple(Furniture(to_rect(b), hgt) for b, hgt in furniture),
        ceiling_height_m=_m(uniform_u(rng, 2.6, 3.2)),
        meta={"style": style, "seed": seed, "rooms": lay.n_rooms, "generator": GENERATOR_VERSION},
    )


def style_of_seed(seed: int) -> str:
    """The style ``generate_plan`` uses for ``seed`` when none is given (a roughly equal mix over seeds).

    Drawn from its own random stream, so ``generate_plan(seed, name)`` equals
    ``generate_plan(seed, name, style_of_seed(seed))`` and a plan's ``meta`` (seed, style) always reproduces it.
    """
    return STYLES[int(np.random.default_rng([seed, 0x5717E]).integers(len(STYLES)))]


def generate_plan_and_raster(seed: int, name: str, style: str | None = None) -> tuple[FloorPlan, PlanRaster]:
    """Like :func:`generate_plan`, also returning the 0.05 m raster that passed the connectivity check."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    if style is None:
        style = style_of_seed(seed)
    if style not in STYLES:
        raise ValueError(f"unknown style {style!r}; choose one of {STYLES}")
    chosen = style
    return checked_build(
        lambda rng: _build(rng, chosen, seed, name),
        lambda attempt: seed if attempt == 0 else [seed, attempt],
        f"seed {seed}: no valid {style!r} plan",
    )


def checked_build(
    build: Callable[[np.random.Generator], FloorPlan],
    attempt_seed: Callable[[int], int | list[int]],
    failure: str,
    attempts: int = MAX_ATTEMPTS,
) -> tuple[FloorPlan, PlanRaster]:
    """Draw a plan with ``build``, validate it, rasterize it at 0.05 m and check it is connected at the robot's
    radius; a failed attempt is drawn again from the generator seeded with ``attempt_seed(attempt)``. Raises
    :class:`PlanError` (``failure``, the attempts and the last problem) when no attempt passes."""
    problems = []
    for attempt in range(attempts):
        rng = np.random.default_rng(attempt_seed(attempt))
        try:
            plan = build(rng)
            validate_plan(plan)
            raster = rasterize(plan, HIGH_RES_M)
            check_connected(raster, ROBOT_RADIUS_M)
        except (Retry, PlanError) as exc:
            problems.append(str(exc))
            continue
        return plan, raster
    raise PlanError(f"{failure} in {attempts} attempts (last: {problems[-1]})")


def generate_plan(seed: int, name: str, style: str | None = None) -> FloorPlan:
    """One floor plan of the paper's dataset, deterministic given ``(seed, style)``.

    ``style`` is one of :data:`STYLES` (office corridor, rooms around a hall, L/U-shaped, internal rooms); ``None``
    draws it from the seed. The plan is validated and connected at robot radius 0.25 m on the 0.05 m raster;
    ``meta`` records ``style``, ``seed``, ``rooms`` (rooms, not counting corridors and halls) and ``generator``.
    Raises :class:`PlanError` naming the seed if no valid plan came out of :data:`MAX_ATTEMPTS` attempts.
    """
    return generate_plan_and_raster(seed, name, style)[0]
