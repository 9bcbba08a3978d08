"""The layout stage of the plan generator: labelled rectangles tiling a building's footprint, one function per style.

A layout is step 1 of :mod:`edge_explorer.world.generator`: rectangles labelled as rooms, corridors (one label may be
several rectangles, e.g. a corridor loop) or a hall, in a canonical frame (long side along x, footprint inside
[0, w] × [0, h]) and in integer units of :data:`UNIT_M`, so every later coordinate is snapped. The footprint is a
rectangle, an L, a U or a rectangle with a corner cut away. ``STYLE_FUNCS`` maps each style to its layout function.
It is kept apart from the generator's geometry, doors and furniture because it is the only part that decides the
shape of a building: the later stages work on any layout, and a new style is one more function here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

UNIT_M = 0.05  # layout grid: every coordinate is a multiple of this

Box = tuple[int, int, int, int]  # x0, y0, x1, y1 in layout units


def _u(metres: float) -> int:
    return int(round(metres / UNIT_M))


class Retry(Exception):
    """An attempt produced a layout the generator does not want (too many rooms, unreachable room, ...)."""


# ---------------------------------------------------------------------------------------------------------------
# Layout: labelled rectangles in a canonical frame (long side along x, footprint inside [0, w] × [0, h])
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class Layout:
    w: int
    h: int
    kinds: list[str] = field(default_factory=lambda: ["outside"])  # kinds[label]; label 0 is outside
    rects: list[tuple[int, Box]] = field(default_factory=list)  # (label, box), painted in order

    def add(self, kind: str, box: Box, label: int | None = None) -> int:
        x0, y0, x1, y1 = box
        if not (0 <= x0 < x1 <= self.w and 0 <= y0 < y1 <= self.h):
            raise Retry(f"layout box {box} outside the {self.w}×{self.h} footprint")
        if label is None:
            self.kinds.append(kind)
            label = len(self.kinds) - 1
        self.rects.append((label, box))
        return label

    def rooms(self, kind: str, boxes: list[Box]) -> None:
        for b in boxes:
            self.add(kind, b)

    @property
    def n_rooms(self) -> int:
        return sum(k == "room" for k in self.kinds)


def uniform_u(rng: np.random.Generator, lo_m: float, hi_m: float) -> int:
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


def _strip(rng: np.random.Generator, box: Box, along_x: bool, min_u: int, max_u: int) -> list[Box]:
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
        room_min = uniform_u(rng, 2.4, 3.6)
        room_max = room_min + uniform_u(rng, 1.0, 3.0)
        return _Sizes(room_min, room_max, uniform_u(rng, 1.2, corridor_max_m))


def _cut_corner(rng: np.random.Generator, lay: Layout, strips: list[list[Box]]) -> list[list[Box]]:
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


def _layout_corridor(rng: np.random.Generator) -> Layout:
    """Office corridor: a long corridor with rooms on one or both sides, end rooms, sometimes a side branch."""
    sz = _Sizes.draw(rng)
    w, h = uniform_u(rng, 12.0, 21.0), uniform_u(rng, 6.0, 11.0)
    lay = Layout(w, h)
    cw = sz.corridor
    two_sided = h - cw >= 2 * _u(2.4) and rng.random() < 0.85
    if two_sided:
        y0 = int(rng.integers(_u(2.4), h - cw - _u(2.4) + 1))
    else:
        y0 = 0 if rng.random() < 0.5 else h - cw
    end_l = uniform_u(rng, 2.5, 4.5) if rng.random() < 0.4 else 0
    end_r = uniform_u(rng, 2.5, 4.5) if rng.random() < 0.4 else 0
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


def _layout_hall(rng: np.random.Generator) -> Layout:
    """Rooms around a central hall (open-plan office, lobby): rooms on two to four sides of the hall."""
    sz = _Sizes.draw(rng)
    w, h = uniform_u(rng, 10.0, 21.0), uniform_u(rng, 7.0, 11.0)
    lay = Layout(w, h)
    db = uniform_u(rng, 2.4, 4.0)
    dt = uniform_u(rng, 2.4, 4.0) if rng.random() < 0.85 else 0
    if h - db - dt < _u(3.0):
        dt = 0
    dl = uniform_u(rng, 2.5, 4.5) if rng.random() < 0.6 else 0
    dr = uniform_u(rng, 2.5, 4.5) if rng.random() < 0.6 else 0
    if w - dl - dr < _u(4.0):
        dl = dr = 0
    if not (dt or dl or dr):  # rooms on at least two sides, or it is just a corridor plan
        dr = uniform_u(rng, 2.5, 4.5)
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


def _layout_lshape(rng: np.random.Generator) -> Layout:
    """L- or U-shaped building: a bottom wing and one or two arms, a corridor that follows the shape."""
    sz = _Sizes.draw(rng, corridor_max_m=2.2)
    cw = sz.corridor
    u_shape = rng.random() < 0.35
    w = uniform_u(rng, 16.0 if u_shape else 14.0, 21.0)
    h = uniform_u(rng, 9.0, 11.0)
    c1 = 0 if rng.random() < 0.3 else uniform_u(rng, 2.4, 4.0)  # rooms below the bottom corridor
    d2 = uniform_u(rng, 2.4, 4.5)  # rooms above it (inner side, towards the notch)
    arm = h - (c1 + cw + d2)
    if arm < _u(2.5):
        c1 = 0
        d2 = max(_u(2.4), h - cw - _u(2.5) - int(rng.integers(0, _u(2.5))))
        arm = h - (cw + d2)
    h1 = c1 + cw + d2  # top of the bottom wing

    def arm_widths() -> tuple[int, int]:
        outer = 0 if rng.random() < 0.3 else uniform_u(rng, 2.4, 4.0)  # rooms on the arm's outer side
        return outer, outer + cw + uniform_u(rng, 2.4, 4.5)

    c2, w2 = arm_widths()
    c2r, w2r = arm_widths() if u_shape else (0, 0)
    if u_shape and w - w2 - w2r < _u(2.5):
        u_shape = False
    lay = Layout(w, h)
    end_r = 0
    if not u_shape and rng.random() < 0.4 and w - w2 >= _u(2.5) + _u(4.0):
        end_r = uniform_u(rng, 2.5, 4.0)
    right = w - c2r if u_shape else w - end_r  # right end of the horizontal corridor
    corridor = lay.add("corridor", (c2, c1, right, c1 + cw))
    strips = [_strip(rng, (0, 0, w, c1), True, sz.room_min, sz.room_max)]
    inner_right = w - c2r - cw if u_shape else w - end_r
    strips.append(_strip(rng, (c2 + cw, c1 + cw, inner_right, h1), True, sz.room_min, sz.room_max))
    if end_r:
        strips.append([(w - end_r, c1, w, h1)])
    arms = [(c2, w2, False)] + ([(c2r, w2r, True)] if u_shape else [])
    for outer, width, mirrored in arms:
        end_t = uniform_u(rng, 2.4, 3.5) if rng.random() < 0.4 else 0
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


def _layout_internal(rng: np.random.Generator) -> Layout:
    """Perimeter rooms, a corridor loop inside them, and a block of internal rooms (no outside wall) in the middle."""
    sz = _Sizes.draw(rng, corridor_max_m=2.0)
    if sz.room_min < _u(3.2):  # three rows of rooms: wider rooms keep the count ≤ MAX_ROOMS
        sz = _Sizes(_u(3.2), max(sz.room_max, _u(5.0)), sz.corridor)
    w, h = uniform_u(rng, 13.0, 21.0), uniform_u(rng, 9.6, 11.0)
    spare = h - _u(9.6)  # above the minimum: 2 × 2.4 m rooms + 2 × 1.2 m corridor + 2.4 m internal rooms
    parts = np.floor(rng.dirichlet(np.ones(5)) * spare).astype(int)
    cw = _u(1.2) + min(int(parts[0]), sz.corridor - _u(1.2))
    db, di = _u(2.4) + int(parts[1]), _u(2.4) + int(parts[2])
    dt = h - db - di - 2 * cw  # the top row takes the rest (≥ 2.4 m)
    lay = Layout(w, h)
    end_l = uniform_u(rng, 2.5, 4.0) if rng.random() < 0.35 else 0
    end_r = uniform_u(rng, 2.5, 4.0) if rng.random() < 0.35 else 0
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


STYLE_FUNCS: dict[str, Callable[[np.random.Generator], Layout]] = {
    "corridor": _layout_corridor,
    "hall": _layout_hall,
    "lshape": _layout_lshape,
    "internal": _layout_internal,
}
