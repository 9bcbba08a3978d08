"""Procedural office floor plans that match the paper's training dataset (DESIGN.md §4).

``generate_plan(seed, name, style)`` draws one building inside the 21 m × 11 m envelope: axis-aligned walls of
0.10–0.20 m, open doors of 0.80–1.20 m, rooms mostly on the perimeter (internal rooms in the ``internal`` style),
L/U-shaped or corner-cut perimeters, tall furniture (shelves, cabinets: part of the 2-D plan) and low furniture
(tables, desks, beds: 3-D only). Every returned plan passes :func:`validate_plan` and is connected at the robot's
radius when rasterized at 0.05 m; the check is part of generation, so a caller never sees a bad plan.

How a plan is made (all lengths are integer multiples of :data:`UNIT_M` = 0.05 m, so every coordinate is snapped):

1. A *layout*: rectangles labelled as rooms, corridors (one label may be several rectangles, e.g. a corridor loop)
   or a hall, tiling a footprint that is a rectangle, an L, a U or a rectangle with a corner cut away.
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
from dataclasses import dataclass, field

import numpy as np

from edge_explorer.errors import PlanError
from edge_explorer.world.grid import HIGH_RES_M
from edge_explorer.world.plan import MIN_DOOR_WIDTH_M, FloorPlan, Furniture, Rect, validate_plan
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, check_connected, rasterize

STYLES: tuple[str, ...] = ("corridor", "hall", "lshape", "internal")
GENERATOR_VERSION = 1  # bump whenever the same (seed, style) would give a different plan
MAX_ATTEMPTS = 6
UNIT_M = 0.05  # layout grid: every coordinate is a multiple of this

MIN_ROOMS, MAX_ROOMS = 3, 14
_MIN_DOOR_U = int(round(MIN_DOOR_WIDTH_M / UNIT_M))  # 16
_MAX_DOOR_U = 24  # 1.20 m
_DOOR_KEEPOUT_U = 16  # furniture stays 0.8 m clear of each door, on both sides
_TALL_GAP_U = 12  # tall items keep 0.6 m from each other (a robot of 0.5 m passes between them)

_Box = tuple[int, int, int, int]  # x0, y0, x1, y1 in layout units


def _u(metres: float) -> int:
    return int(round(metres / UNIT_M))


def _m(units: int) -> float:
    return round(units * UNIT_M, 2)


class _Retry(Exception):
    """An attempt produced a layout the generator does not want (too many rooms, unreachable room, ...)."""


# ---------------------------------------------------------------------------------------------------------------
# Layout: labelled rectangles in a canonical frame (long side along x, footprint inside [0, w] × [0, h])
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class _Layout:
    w: int
    h: int
    kinds: list[str] = field(default_factory=lambda: ["outside"])  # kinds[label]; label 0 is outside
    rects: list[tuple[int, _Box]] = field(default_factory=list)  # (label, box), painted in order

    def add(self, kind: str, box: _Box, label: int | None = None) -> int:
        x0, y0, x1, y1 = box
        if not (0 <= x0 < x1 <= self.w and 0 <= y0 < y1 <= self.h):
            raise _Retry(f"layout box {box} outside the {self.w}×{self.h} footprint")
        if label is None:
            self.kinds.append(kind)
            label = len(self.kinds) - 1
        self.rects.append((label, box))
        return label

    def rooms(self, kind: str, boxes: list[_Box]) -> None:
        for b in boxes:
            self.add(kind, b)

    @property
    def n_rooms(self) -> int:
        return sum(k == "room" for k in self.kinds)


def _uniform_u(rng: np.random.Generator, lo_m: float, hi_m: float) -> int:
    """A length drawn uniformly in [lo, hi] metres, in layout units."""
    lo, hi = _u(lo_m), _u(hi_m)
    return int(rng.integers(lo, hi + 1)) if hi > lo else lo


def _split(rng: np.random.Generator, length: int, min_u: int, max_u: int) -> list[int]:
    """Cut a strip of ``length`` units into pieces of about [min_u, max_u] units; returns the piece lengths."""
    n_lo = max(1, -(-length // max_u))
    n_hi = max(n_lo, length // min_u)
    n = int(rng.integers(n_lo, n_hi + 1))
    base = length / n
    # widths vary around the mean, but stay ≥ min(min_u, base) so no piece becomes a sliver
    floor = min(min_u, int(base))
    spare = length - floor * n
    share = rng.dirichlet(np.full(n, 4.0)) * spare
    cuts = np.round(np.cumsum(share)).astype(int)
    widths = np.diff(np.concatenate(([0], cuts))) + floor
    widths[-1] += length - int(widths.sum())
    return [int(x) for x in widths]


def _strip(rng: np.random.Generator, box: _Box, along_x: bool, min_u: int, max_u: int) -> list[_Box]:
    """Rooms side by side filling ``box``, the cuts running across the strip."""
    x0, y0, x1, y1 = box
    if x1 <= x0 or y1 <= y0:
        return []
    out = []
    pos = x0 if along_x else y0
    for width in _split(rng, (x1 - x0) if along_x else (y1 - y0), min_u, max_u):
        out.append((pos, y0, pos + width, y1) if along_x else (x0, pos, x1, pos + width))
        pos += width
    return out


@dataclass(frozen=True)
class _Sizes:
    """Per-plan size ranges (units) that make plans visibly different from each other."""

    room_min: int
    room_max: int
    corridor: int

    @staticmethod
    def draw(rng: np.random.Generator, corridor_max_m: float = 2.5) -> _Sizes:
        room_min = _uniform_u(rng, 2.4, 3.6)
        room_max = room_min + _uniform_u(rng, 1.0, 3.0)
        return _Sizes(room_min, room_max, _uniform_u(rng, 1.2, corridor_max_m))


def _cut_corner(rng: np.random.Generator, lay: _Layout, strips: list[list[_Box]]) -> list[list[_Box]]:
    """Drop one room that sits in a corner of the footprint (a non-convex perimeter), if a strip allows it."""
    corners = {(0, 0), (lay.w, 0), (0, lay.h), (lay.w, lay.h)}
    options = []
    for s, rooms in enumerate(strips):
        if len(rooms) < 3:
            continue
        for r, (x0, y0, x1, y1) in enumerate(rooms):
            if r in (0, len(rooms) - 1) and corners & {(x0, y0), (x1, y0), (x0, y1), (x1, y1)}:
                options.append((s, r))
    if not options:
        return strips
    s, r = options[int(rng.integers(len(options)))]
    strips = [list(x) for x in strips]
    del strips[s][r]
    return strips


def _layout_corridor(rng: np.random.Generator) -> _Layout:
    """Office corridor: a long corridor with rooms on one or both sides, end rooms, sometimes a side branch."""
    sz = _Sizes.draw(rng)
    w, h = _uniform_u(rng, 12.0, 21.0), _uniform_u(rng, 6.0, 11.0)
    lay = _Layout(w, h)
    cw = sz.corridor
    two_sided = h - cw >= 2 * _u(2.4) and rng.random() < 0.85
    if two_sided:
        y0 = int(rng.integers(_u(2.4), h - cw - _u(2.4) + 1))
    else:
        y0 = 0 if rng.random() < 0.5 else h - cw
    end_l = _uniform_u(rng, 2.5, 4.5) if rng.random() < 0.4 else 0
    end_r = _uniform_u(rng, 2.5, 4.5) if rng.random() < 0.4 else 0
    if w - end_l - end_r < _u(6.0):
        end_l = end_r = 0
    corridor = lay.add("corridor", (end_l, y0, w - end_r, y0 + cw))
    sides = [s for s in ((0, y0), (y0 + cw, h)) if s[1] - s[0] > 0]
    strips = []
    branch_side = int(rng.integers(len(sides))) if rng.random() < 0.35 else -1
    for k, (s0, s1) in enumerate(sides):
        if k == branch_side and w - end_l - end_r >= 2 * sz.room_min + _u(2.0):
            bw = int(rng.integers(_u(1.2), min(cw, _u(2.0)) + 1))
            at = end_l + int(rng.integers(sz.room_min, w - end_l - end_r - sz.room_min - bw + 1))
            lay.add("corridor", (at, s0, at + bw, s1), corridor)
            rooms = _strip(rng, (end_l, s0, at, s1), True, sz.room_min, sz.room_max)
            rooms += _strip(rng, (at + bw, s0, w - end_r, s1), True, sz.room_min, sz.room_max)
        else:
            rooms = _strip(rng, (end_l, s0, w - end_r, s1), True, sz.room_min, sz.room_max)
        strips.append(rooms)
    if rng.random() < 0.3:
        strips = _cut_corner(rng, lay, strips)
    for rooms in strips:
        lay.rooms("room", rooms)
    for x0, x1 in ((0, end_l), (w - end_r, w)):
        if x1 > x0:
            split_end = h >= _u(8.0) and rng.random() < 0.5
            lay.rooms("room", _strip(rng, (x0, 0, x1, h), False, h // 2, h) if split_end else [(x0, 0, x1, h)])
    return lay


def _layout_hall(rng: np.random.Generator) -> _Layout:
    """Rooms around a central hall (open-plan office, lobby): rooms on two to four sides of the hall."""
    sz = _Sizes.draw(rng)
    w, h = _uniform_u(rng, 10.0, 21.0), _uniform_u(rng, 7.0, 11.0)
    lay = _Layout(w, h)
    db = _uniform_u(rng, 2.4, 4.0)
    dt = _uniform_u(rng, 2.4, 4.0) if rng.random() < 0.85 else 0
    if h - db - dt < _u(3.0):
        dt = 0
    dl = _uniform_u(rng, 2.5, 4.5) if rng.random() < 0.6 else 0
    dr = _uniform_u(rng, 2.5, 4.5) if rng.random() < 0.6 else 0
    if w - dl - dr < _u(4.0):
        dl = dr = 0
    if not (dt or dl or dr):  # rooms on at least two sides, or it is just a corridor plan
        dr = _uniform_u(rng, 2.5, 4.5)
    lay.add("hall", (dl, db, w - dr, h - dt))
    strips = [
        _strip(rng, (0, 0, dl, h), False, sz.room_min, sz.room_max),
        _strip(rng, (w - dr, 0, w, h), False, sz.room_min, sz.room_max),
        _strip(rng, (dl, 0, w - dr, db), True, sz.room_min, sz.room_max),
        _strip(rng, (dl, h - dt, w - dr, h), True, sz.room_min, sz.room_max),
    ]
    if rng.random() < 0.35:
        strips = _cut_corner(rng, lay, strips)
    for rooms in strips:
        lay.rooms("room", rooms)
    return lay


def _layout_lshape(rng: np.random.Generator) -> _Layout:
    """L- or U-shaped building: a bottom wing and one or two arms, a corridor that follows the shape."""
    sz = _Sizes.draw(rng, corridor_max_m=2.2)
    cw = sz.corridor
    u_shape = rng.random() < 0.35
    w = _uniform_u(rng, 16.0 if u_shape else 14.0, 21.0)
    h = _uniform_u(rng, 9.0, 11.0)
    c1 = 0 if rng.random() < 0.3 else _uniform_u(rng, 2.4, 4.0)  # rooms below the bottom corridor
    d2 = _uniform_u(rng, 2.4, 4.5)  # rooms above it (inner side, towards the notch)
    arm = h - (c1 + cw + d2)
    if arm < _u(2.5):
        c1 = 0
        d2 = max(_u(2.4), h - cw - _u(2.5) - int(rng.integers(0, _u(2.5))))
        arm = h - (cw + d2)
    h1 = c1 + cw + d2  # top of the bottom wing

    def arm_widths() -> tuple[int, int]:
        outer = 0 if rng.random() < 0.3 else _uniform_u(rng, 2.4, 4.0)  # rooms on the arm's outer side
        return outer, outer + cw + _uniform_u(rng, 2.4, 4.5)

    c2, w2 = arm_widths()
    c2r, w2r = arm_widths() if u_shape else (0, 0)
    if u_shape and w - w2 - w2r < _u(2.5):
        u_shape = False
    lay = _Layout(w, h)
    end_r = 0
    if not u_shape and rng.random() < 0.4 and w - w2 >= _u(2.5) + _u(4.0):
        end_r = _uniform_u(rng, 2.5, 4.0)
    right = w - c2r if u_shape else w - end_r  # right end of the horizontal corridor
    corridor = lay.add("corridor", (c2, c1, right, c1 + cw))
    strips = [_strip(rng, (0, 0, w, c1), True, sz.room_min, sz.room_max)]
    inner_right = w - c2r - cw if u_shape else w - end_r
    strips.append(_strip(rng, (c2 + cw, c1 + cw, inner_right, h1), True, sz.room_min, sz.room_max))
    if end_r:
        strips.append([(w - end_r, c1, w, h1)])
    arms = [(c2, w2, False)] + ([(c2r, w2r, True)] if u_shape else [])
    for outer, width, mirrored in arms:
        end_t = _uniform_u(rng, 2.4, 3.5) if rng.random() < 0.4 else 0
        if arm < end_t + _u(2.4):
            end_t = 0

        def fx(x0: int, x1: int, mirrored: bool = mirrored) -> tuple[int, int]:
            return (w - x1, w - x0) if mirrored else (x0, x1)

        cx0, cx1 = fx(outer, outer + cw)
        lay.add("corridor", (cx0, c1, cx1, h - end_t), corridor)
        ox0, ox1 = fx(0, outer)
        strips.append(_strip(rng, (ox0, c1, ox1, h), False, sz.room_min, sz.room_max))
        ix0, ix1 = fx(outer + cw, width)
        strips.append(_strip(rng, (ix0, h1, ix1, h - end_t), False, sz.room_min, sz.room_max))
        if end_t:
            ex0, ex1 = fx(outer, width)
            strips.append([(ex0, h - end_t, ex1, h)])
    for rooms in strips:
        lay.rooms("room", rooms)
    return lay


def _layout_internal(rng: np.random.Generator) -> _Layout:
    """Perimeter rooms, a corridor loop inside them, and a block of internal rooms (no outside wall) in the middle."""
    sz = _Sizes.draw(rng, corridor_max_m=2.0)
    if sz.room_min < _u(3.2):  # three rows of rooms: wider rooms keep the count ≤ MAX_ROOMS
        sz = _Sizes(_u(3.2), max(sz.room_max, _u(5.0)), sz.corridor)
    w, h = _uniform_u(rng, 13.0, 21.0), _uniform_u(rng, 9.6, 11.0)
    spare = h - _u(9.6)  # above the minimum: 2 × 2.4 m rooms + 2 × 1.2 m corridor + 2.4 m internal rooms
    parts = np.floor(rng.dirichlet(np.ones(5)) * spare).astype(int)
    cw = _u(1.2) + min(int(parts[0]), sz.corridor - _u(1.2))
    db, di = _u(2.4) + int(parts[1]), _u(2.4) + int(parts[2])
    dt = h - db - di - 2 * cw  # the top row takes the rest (≥ 2.4 m)
    lay = _Layout(w, h)
    end_l = _uniform_u(rng, 2.5, 4.0) if rng.random() < 0.35 else 0
    end_r = _uniform_u(rng, 2.5, 4.0) if rng.random() < 0.35 else 0
    if w - end_l - end_r - 2 * cw < _u(5.0):
        end_l = end_r = 0
    x0, x1 = end_l, w - end_r
    corridor = lay.add("corridor", (x0, db, x1, db + cw))
    lay.add("corridor", (x0, h - dt - cw, x1, h - dt), corridor)
    lay.add("corridor", (x0, db + cw, x0 + cw, h - dt - cw), corridor)
    lay.add("corridor", (x1 - cw, db + cw, x1, h - dt - cw), corridor)
    strips = [
        _strip(rng, (x0, 0, x1, db), True, sz.room_min, sz.room_max),
        _strip(rng, (x0, h - dt, x1, h), True, sz.room_min, sz.room_max),
    ]
    if rng.random() < 0.25:
        strips = _cut_corner(rng, lay, strips)
    for rooms in strips:
        lay.rooms("room", rooms)
    inner = (x0 + cw, db + cw, x1 - cw, h - dt - cw)  # meeting rooms, storage: a little larger
    lay.rooms("room", _strip(rng, inner, True, sz.room_min + _u(0.8), sz.room_max + _u(1.5)))
    for e0, e1 in ((0, end_l), (w - end_r, w)):
        if e1 > e0:
            lay.rooms("room", _strip(rng, (e0, 0, e1, h), False, sz.room_min + _u(1.0), sz.room_max + _u(1.0)))
    return lay


_STYLE_FUNCS: dict[str, Callable[[np.random.Generator], _Layout]] = {
    "corridor": _layout_corridor,
    "hall": _layout_hall,
    "lshape": _layout_lshape,
    "internal": _layout_internal,
}


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
    walls: list[_Box]
    segments: dict[tuple[int, int], list[_Segment]]  # (label_a, label_b), a < b → shared boundary stretches
    room_boxes: dict[int, _Box]  # free interior (inside the walls) of every single-rectangle region


def _label_grid(lay: _Layout) -> tuple[list[int], list[int], np.ndarray]:
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
            raise _Retry("footprint outline is not a single loop")
    if len(loop) != len(nxt):
        raise _Retry("footprint has holes or touching corners")
    n = len(loop)
    corners = []
    for k in range(n):
        (ax, ay), (bx, by), (cx, cy) = loop[k - 1], loop[k], loop[(k + 1) % n]
        if (bx - ax) * (cy - by) - (by - ay) * (cx - bx) != 0:
            corners.append((xs[bx], ys[by]))
    return corners


def _perimeter_walls(outline: list[tuple[int, int]], t: int) -> list[_Box]:
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


def _geometry(lay: _Layout, t_int: int, t_ext: int) -> _Geometry:
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
    lay: _Layout, xs: list[int], ys: list[int], grid: np.ndarray, lo: int, hi: int, t_ext: int
) -> dict[int, _Box]:
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
def _door_on(rng: np.random.Generator, seg: _Segment, t_int: int) -> _Box:
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
    rng: np.random.Generator, lay: _Layout, geo: _Geometry, t_int: int
) -> tuple[list[_Box], dict[int, list[_Box]]]:
    """Spanning tree from the hub(s) over feasible adjacencies, then a few loop-making extra doors."""
    feasible: dict[tuple[int, int], list[_Segment]] = {}
    for key, segs in geo.segments.items():
        ok = [s for s in segs if s.usable >= _MIN_DOOR_U]
        if ok:
            feasible[key] = ok
    labels = range(1, len(lay.kinds))
    hubs = [lb for lb in labels if lay.kinds[lb] in ("corridor", "hall")]
    in_tree = {hubs[0] if hubs else 1}
    chosen: list[tuple[int, int]] = []
    while len(in_tree) < len(lay.kinds) - 1:
        frontier = sorted(k for k in feasible if (k[0] in in_tree) != (k[1] in in_tree))
        if not frontier:
            raise _Retry("a room has no wall long enough for a door to the rest of the building")
        from_hub = [k for k in frontier if (k[0] if k[0] in in_tree else k[1]) in hubs]
        pool = from_hub or frontier
        key = pool[int(rng.integers(len(pool)))]
        chosen.append(key)
        in_tree.update(key)
    p_extra = float(rng.uniform(0.0, 0.3))
    for key in sorted(feasible):
        if key not in chosen and rng.random() < (0.6 if (key[0] in hubs or key[1] in hubs) else p_extra):
            chosen.append(key)
    doors: list[_Box] = []
    by_label: dict[int, list[_Box]] = {lb: [] for lb in labels}
    for key in chosen:
        segs = feasible[key]
        seg = max(segs, key=lambda s: s.usable) if rng.random() < 0.7 else segs[int(rng.integers(len(segs)))]
        door = _door_on(rng, seg, t_int)
        doors.append(door)
        by_label[key[0]].append(door)
        by_label[key[1]].append(door)
    return doors, by_label


def _overlap(a: _Box, b: _Box, gap: int = 0) -> bool:
    return a[0] - gap < b[2] and b[0] - gap < a[2] and a[1] - gap < b[3] and b[1] - gap < a[3]


def _furnish(rng: np.random.Generator, box: _Box, doors: list[_Box], n_items: int) -> list[tuple[_Box, float]]:
    """Up to ``n_items`` boxes in a room's free rectangle, out of the doors' keep-out zones."""
    x0, y0, x1, y1 = box
    keepout = [
        (d[0] - _DOOR_KEEPOUT_U, d[1] - _DOOR_KEEPOUT_U, d[2] + _DOOR_KEEPOUT_U, d[3] + _DOOR_KEEPOUT_U) for d in doors
    ]
    items: list[tuple[_Box, float, bool]] = []
    for _ in range(2 * n_items):
        if len(items) >= n_items:
            break
        tall = rng.random() < 0.45
        against_wall = tall or rng.random() < 0.6
        if tall:
            depth, length = _uniform_u(rng, 0.3, 0.6), _uniform_u(rng, 0.6, 2.0)
            height = _m(_uniform_u(rng, 1.6, 2.2))
        else:
            depth, length = _uniform_u(rng, 0.6, 1.6), _uniform_u(rng, 0.6, 2.0)
            height = _m(_uniform_u(rng, 0.4, 1.2))
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
    lay = _STYLE_FUNCS[style](rng)
    if not MIN_ROOMS <= lay.n_rooms <= MAX_ROOMS:
        raise _Retry(f"{lay.n_rooms} rooms")
    t_int = int(rng.integers(2, 4))  # 0.10 or 0.15 m
    t_ext = int(rng.integers(3, 5))  # 0.15 or 0.20 m
    geo = _geometry(lay, t_int, t_ext)
    doors, doors_of = _place_doors(rng, lay, geo, t_int)
    furniture: list[tuple[_Box, float]] = []
    for label, box in geo.room_boxes.items():
        kind = lay.kinds[label]
        area_m2 = (box[2] - box[0]) * (box[3] - box[1]) * UNIT_M**2
        cap = min(6, int(area_m2 / 2.5)) if kind == "room" else (min(6, int(area_m2 / 8)) if kind == "hall" else 0)
        if cap > 0:
            furniture += _furnish(rng, box, doors_of[label], int(rng.integers(0, cap + 1)))
    sym = _symmetry(int(rng.integers(8)), lay.w, lay.h)

    def to_rect(b: _Box) -> Rect:
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
        ceiling_height_m=_m(_uniform_u(rng, 2.6, 3.2)),
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
    problems = []
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng(seed if attempt == 0 else [seed, attempt])
        try:
            plan = _build(rng, style, seed, name)
            validate_plan(plan)
            raster = rasterize(plan, HIGH_RES_M)
            check_connected(raster, ROBOT_RADIUS_M)
        except (_Retry, PlanError) as exc:
            problems.append(str(exc))
            continue
        return plan, raster
    raise PlanError(f"seed {seed}: no valid {style!r} plan in {MAX_ATTEMPTS} attempts (last: {problems[-1]})")


def generate_plan(seed: int, name: str, style: str | None = None) -> FloorPlan:
    """One floor plan of the paper's dataset, deterministic given ``(seed, style)``.

    ``style`` is one of :data:`STYLES` (office corridor, rooms around a hall, L/U-shaped, internal rooms); ``None``
    draws it from the seed. The plan is validated and connected at robot radius 0.25 m on the 0.05 m raster;
    ``meta`` records ``style``, ``seed``, ``rooms`` (rooms, not counting corridors and halls) and ``generator``.
    Raises :class:`PlanError` naming the seed if no valid plan came out of :data:`MAX_ATTEMPTS` attempts.
    """
    return generate_plan_and_raster(seed, name, style)[0]
