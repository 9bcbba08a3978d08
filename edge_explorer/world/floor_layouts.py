"""The layout stage of whole office floors (40–200 m): corridor spines, wings, rows of rooms, stairwell cores.

A floor is drawn as :class:`~edge_explorer.world.layouts.Layout` rectangles, the same currency as the 21 × 11 m
styles, so :mod:`edge_explorer.world.floors` hands it to the generator's geometry, door and furniture stages.

How a floor is laid out (canonical frame: the spine along x, everything in units of 0.05 m):

* a **spine** of length ``L``: a double-loaded corridor (room row | corridor | room row; one of the two rows holds
  offices) or a **ring** (room row | corridor | inner block | corridor | room row, joined by cross corridors at both
  ends and every 30–60 m), so the corridor is a loop;
* **wings** off the spine (shape ``bar``: none, ``L``: one at an end, ``T``: one in the middle, ``U``: one at each
  end, ``comb``: several on one side, ``H``: on both sides), each a double-loaded corridor that opens into the
  spine's corridor (one corridor label: no wall, no door between them) and may end in an end room;
* every room row is cut into rooms: an **office row** (4.8–7 m deep) into **offices** (3.3–6 m wide) with a few
  **labs** (8–16 m), **lecture** rooms (10–20 m) and **halls** (open-plan areas of 12–40 m, hubs like the
  corridor); a **deep row** (10–18 m) into halls, lecture rooms and labs only — the wide open space of real
  university and office floors (the floors' module docstring measures it); every 50–100 m of room row (25–50 m of
  corridor) a **stairwell core**: a stair room (kind ``core``, with a door) beside a lift shaft (kind ``shaft``)
  that the floor builder fills solid: closed, not flyable inside;
* a ring's inner block is cut by its cross corridors into segments, each an **atrium** (one hall), one deep row, or
  two rows back to back (each opening onto its own corridor).

Corridor labels are one region; every other label is one rectangle. Labels of kind ``shaft`` must get no door.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from edge_explorer.world.layouts import Box, Layout, Retry, uniform_u

_U = 20  # layout units per metre


def _u(metres: float) -> int:
    return int(round(metres * _U))


SHAPES: tuple[str, ...] = ("bar", "L", "T", "U", "comb", "H")


@dataclass(frozen=True)
class FloorConfig:
    """Size ranges of a whole floor, in metres (see the module docstring of :mod:`edge_explorer.world.floors` for
    how they compare with real floors). Row mixes are ``(p_hall, p_lecture, p_lab)``; the rest of a row is offices
    (office rows) or labs (deep rows); each floor scales them by a factor in [0.5, 1.5]."""

    length_m: tuple[float, float] = (40.0, 200.0)  # the spine (the floor's long side); drawn uniformly
    corridor_m: tuple[float, float] = (2.4, 3.2)
    office_depth_m: tuple[float, float] = (4.8, 7.0)  # depth of a room row (perpendicular to the corridor)
    deep_depth_m: tuple[float, float] = (10.0, 18.0)  # a deep row: open-plan halls, lecture rooms, labs
    p_deep_row: float = 0.6
    office_width_m: tuple[float, float] = (3.3, 6.0)
    lab_width_m: tuple[float, float] = (8.0, 16.0)
    lecture_width_m: tuple[float, float] = (10.0, 20.0)
    hall_width_m: tuple[float, float] = (12.0, 40.0)
    office_row_mix: tuple[float, float, float] = (0.06, 0.04, 0.12)
    deep_row_mix: tuple[float, float, float] = (0.40, 0.25, 0.35)
    core_spacing_m: tuple[float, float] = (50.0, 100.0)  # of room row: ~25–50 m of corridor
    stair_m: tuple[float, float] = (3.0, 4.2)
    shaft_m: tuple[float, float] = (1.8, 2.6)
    p_ring: float = 0.35  # a ring (loop) corridor, when the floor is at least 50 m long
    inner_depth_m: tuple[float, float] = (10.0, 26.0)  # the ring's inner block
    p_atrium: float = 0.35  # an inner block segment (between cross corridors) left as one open atrium
    wing_length_m: tuple[float, float] = (10.0, 45.0)
    wing_gap_m: float = 8.0  # courtyard between neighbouring wings (the footprint keeps no holes)
    max_size_m: tuple[float, float] = (200.0, 120.0)  # long side, short side


class _RowFiller:
    """Cuts room rows into offices, labs, lecture rooms, halls and cores; one per floor, so cores are spaced along
    all rows. A row at least ``deep_depth_m[0]`` deep is a deep row: no cellular offices, mostly open space."""

    def __init__(self, rng: np.random.Generator, cfg: FloorConfig, lay: Layout) -> None:
        self.rng, self.cfg, self.lay = rng, cfg, lay
        self.room_min = uniform_u(rng, cfg.office_width_m[0], cfg.office_width_m[0] + 0.6)
        self.room_max = max(self.room_min + _u(0.6), uniform_u(rng, cfg.office_width_m[1] - 1.0, cfg.office_width_m[1]))
        self.mix = {
            deep: tuple(p * float(rng.uniform(0.5, 1.5)) for p in (cfg.deep_row_mix if deep else cfg.office_row_mix))
            for deep in (False, True)
        }
        self.spacing = uniform_u(rng, *cfg.core_spacing_m)
        self.since_core = int(self.spacing * rng.uniform(0.3, 0.8))

    def _pieces(self, length: int, deep: bool) -> list[tuple[str, int]]:
        rng, cfg = self.rng, self.cfg
        least = _u(cfg.lab_width_m[0]) // 2 if deep else self.room_min  # the narrowest piece a row leaves
        kinds = (("hall", cfg.hall_width_m), ("lecture", cfg.lecture_width_m), ("lab", cfg.lab_width_m))
        out: list[tuple[str, int]] = []
        rest = length
        while rest > 0:
            if rest < 2 * least:  # the last piece: one room takes the rest
                out.append(("room" if rest <= _u(cfg.lab_width_m[0]) else "lab", rest))
                break
            stair, shaft = uniform_u(rng, *cfg.stair_m), uniform_u(rng, *cfg.shaft_m)
            r = rng.random()
            if self.since_core >= self.spacing and rest >= stair + shaft + least:
                pair = [("core", stair), ("shaft", shaft)]
                out += pair if rng.random() < 0.5 else pair[::-1]
                self.since_core = 0
                rest -= stair + shaft
                continue
            if deep:
                kind, width = "lab", uniform_u(rng, cfg.lab_width_m[0], min(cfg.lab_width_m[1], rest / _U))
            else:
                kind, width = "room", int(rng.integers(self.room_min, self.room_max + 1))
            for p, (k, (lo, hi)) in zip(itertools.accumulate(self.mix[deep]), kinds, strict=True):
                if r < p:
                    if rest >= _u(lo) + least:
                        kind, width = k, uniform_u(rng, lo, min(hi, rest / _U))
                    break
            if rest - width < least:
                width = rest
            out.append((kind, width))
            self.since_core += width
            rest -= width
        return out

    def fill(self, box: Box, along_x: bool) -> None:
        """Cut the row ``box`` across its length (``along_x``: the row runs along x) and add the rooms."""
        x0, y0, x1, y1 = box
        pos = x0 if along_x else y0
        deep = ((y1 - y0) if along_x else (x1 - x0)) >= _u(self.cfg.deep_depth_m[0])
        for kind, width in self._pieces((x1 - x0) if along_x else (y1 - y0), deep):
            self.lay.add(kind, (pos, y0, pos + width, y1) if along_x else (x0, pos, x1, pos + width))
            pos += width

    def end_block(self, box: Box, along_x: bool) -> None:
        """A block at the end of a corridor: cut like a row when long enough, else one room, lab or hall."""
        x0, y0, x1, y1 = box
        length, short = ((x1 - x0), (y1 - y0)) if along_x else ((y1 - y0), (x1 - x0))
        if length >= 2 * self.room_min + _u(1.0) and self.rng.random() < 0.6:
            self.fill(box, along_x)
        elif min(length, short) >= _u(self.cfg.hall_width_m[0]) and self.rng.random() < 0.5:
            self.lay.add("hall", box)
        else:
            self.lay.add("lab" if length * short > _u(6.0) ** 2 else "room", box)


@dataclass(frozen=True)
class _Wing:
    x: int  # left edge
    up: bool  # above the spine (else below)
    length: int  # beyond the spine's edge
    left: int  # room row depth left of its corridor
    corridor: int
    right: int
    end: int  # end block at its tip (0: the corridor reaches the outer wall)

    @property
    def width(self) -> int:
        return self.left + self.corridor + self.right


def _depth(rng: np.random.Generator, cfg: FloorConfig) -> int:
    return uniform_u(rng, *(cfg.deep_depth_m if rng.random() < cfg.p_deep_row else cfg.office_depth_m))


def _wings(rng: np.random.Generator, cfg: FloorConfig, shape: str, length: int, cw: int, room: int) -> list[_Wing]:
    """The wings of ``shape``; ``room``: how far a wing may reach beyond the spine (the short side's limit)."""
    room //= 2 if shape == "H" else 1

    def wing(x: int, up: bool, align: str = "left") -> _Wing:
        """A wing whose left edge is ``x`` (align "left"), whose right edge is ``x`` ("right") or centred on x."""
        left, right = _depth(rng, cfg), _depth(rng, cfg)
        wcw = min(cw, uniform_u(rng, cfg.corridor_m[0], cfg.corridor_m[1]))
        hi = min(cfg.wing_length_m[1], max(length / _U * 0.6, 12.0), room / _U)
        if hi < cfg.wing_length_m[0]:
            raise Retry("no room for a wing within the short side")
        wl = uniform_u(rng, cfg.wing_length_m[0], hi)
        end = _depth(rng, cfg) if rng.random() < 0.6 and wl >= _u(10.0) else 0
        width = left + wcw + right
        x = {"left": x, "right": x - width, "centre": x - width // 2}[align]
        return _Wing(min(max(x, 0), length - width), up, wl, left, wcw, right, end)

    if shape == "bar":
        return []
    if shape == "L":
        return [wing(length, True, "right") if rng.random() < 0.5 else wing(0, True)]
    if shape == "U":
        return [wing(0, True), wing(length, True, "right")]
    if shape == "T":
        return [wing(int(rng.integers(length // 3, 2 * length // 3)), True, "centre")]
    # comb / H: wings at spaced positions on one side (comb) or both (H)
    gap = _u(cfg.wing_gap_m)
    out: list[_Wing] = []
    for up in (True, False) if shape == "H" else (True,):
        x = 0 if rng.random() < 0.5 else int(rng.integers(0, _u(15.0)))
        while True:
            w = wing(x, up)
            if x + w.width > length:
                break
            out.append(w)
            x += w.width + gap + int(rng.integers(0, _u(20.0)))
        if shape == "comb" and len(out) < 2:
            raise Retry("a comb needs two wings")
    if not out:
        raise Retry("no room for a wing")
    return out


def floor_layout(rng: np.random.Generator, cfg: FloorConfig | None = None) -> tuple[Layout, str, bool]:
    """One whole floor's layout, its shape (one of :data:`SHAPES`) and whether its spine is a ring corridor;
    deterministic given ``rng``."""
    cfg = cfg or FloorConfig()
    length = uniform_u(rng, *cfg.length_m)
    cw = uniform_u(rng, *cfg.corridor_m)
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    ring = length >= _u(50.0) and rng.random() < cfg.p_ring
    d_lo, d_hi = _depth(rng, cfg), uniform_u(rng, *cfg.office_depth_m)  # one spine row at least holds offices
    if rng.random() < 0.5:
        d_lo, d_hi = d_hi, d_lo
    d_in = uniform_u(rng, *cfg.inner_depth_m) if ring else 0
    spine_depth = d_lo + cw + (d_in + cw if ring else 0) + d_hi
    wings = _wings(rng, cfg, shape, length, cw, _u(cfg.max_size_m[1]) - spine_depth)
    below = max([w.length for w in wings if not w.up], default=0)
    above = max([w.length for w in wings if w.up], default=0)
    h = below + spine_depth + above
    if max(length, h) > _u(cfg.max_size_m[0]) or min(length, h) > _u(cfg.max_size_m[1]):
        raise Retry(f"floor of {length / _U:.1f} m × {h / _U:.1f} m is too large")
    lay = Layout(max(length, 1), h)
    fill = _RowFiller(rng, cfg, lay)

    # spine corridors (one label), end blocks
    y_lo = below + d_lo  # bottom edge of the (lower) corridor
    y_hi = below + spine_depth - d_hi  # top edge of the (upper) corridor
    end_l = 0 if any(w.x == 0 for w in wings) or rng.random() < 0.5 else _depth(rng, cfg)
    end_r = 0 if any(w.x + w.width == length for w in wings) or rng.random() < 0.5 else _depth(rng, cfg)
    corridor = lay.add("corridor", (end_l, y_lo, length - end_r, y_lo + cw))
    if ring:
        lay.add("corridor", (end_l, y_hi - cw, length - end_r, y_hi), corridor)
        cuts = [end_l]
        x = end_l + cw
        while length - end_r - x > _u(60.0):
            x += uniform_u(rng, 30.0, 60.0)
            cuts.append(x)
        cuts.append(length - end_r - cw)
        if cuts[-1] - cuts[-2] < _u(8.0):
            del cuts[-2]
        for c in cuts:
            lay.add("corridor", (c, y_lo + cw, c + cw, y_hi - cw), corridor)
        # each segment of the inner block: an atrium, one deep row, or two rows back to back (one per corridor)
        mid = y_lo + cw + d_in // 2
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            r = rng.random()
            if r < cfg.p_atrium and b - a - cw <= _u(cfg.hall_width_m[1] * 1.5):
                lay.add("hall", (a + cw, y_lo + cw, b, y_hi - cw))
                continue
            two_rows = d_in >= 2 * _u(cfg.office_depth_m[0]) and r < (1.0 + cfg.p_atrium) / 2
            for r0, r1 in [(y_lo + cw, mid), (mid, y_hi - cw)] if two_rows else [(y_lo + cw, y_hi - cw)]:
                fill.fill((a + cw, r0, b, r1), True)
    for x0, x1 in ((0, end_l), (length - end_r, length)):
        if x1 > x0:
            fill.end_block((x0, below, x1, below + spine_depth), False)

    # spine rows, cut where a wing's corridor crosses them
    for up, (r0, r1) in ((False, (below, y_lo)), (True, (y_hi, below + spine_depth))):
        crossings = sorted((w.x + w.left, w.x + w.left + w.corridor) for w in wings if w.up == up)
        pos = end_l
        for c0, c1 in crossings + [(length - end_r, length - end_r)]:
            if c0 > pos:
                fill.fill((pos, r0, c0, r1), True)
            pos = c1
    # wings: corridor from the spine's corridor to the tip, rows on both sides, an end block
    for w in wings:
        cx0, cx1 = w.x + w.left, w.x + w.left + w.corridor
        if w.up:
            base, tip = below + spine_depth, below + spine_depth + w.length
            lay.add("corridor", (cx0, y_hi, cx1, tip - w.end), corridor)
            rows = (base, tip - w.end)
            end = (w.x, tip - w.end, w.x + w.width, tip)
        else:
            base, tip = below, below - w.length
            lay.add("corridor", (cx0, tip + w.end, cx1, y_lo), corridor)
            rows = (tip + w.end, base)
            end = (w.x, tip, w.x + w.width, tip + w.end)
        fill.fill((w.x, rows[0], cx0, rows[1]), False)
        fill.fill((cx1, rows[0], w.x + w.width, rows[1]), False)
        if w.end:
            fill.end_block(end, True)
    return lay, shape, ring
