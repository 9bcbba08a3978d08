"""Whole office floors of 40–200 m to learn from (issue #55): generator, train / val / test splits, references.

``generate_floor(seed, name)`` draws one floor with :func:`~edge_explorer.world.floor_layouts.floor_layout`
(corridor spines — straight, L, T, U, comb, H, or a ring around an inner block — wings, rows of offices, labs,
lecture rooms, open-plan halls and atria, and stairwell cores) and builds it with the 21 × 11 m generator's own stages
(:mod:`edge_explorer.world.generator`): label grid → walls → doors on a spanning tree from the corridor (so every
room is reachable at the robot's radius) → furniture → a random symmetry → :func:`validate_plan` and the
connectivity check at 0.05 m; a failed attempt is retried with a derived seed. Lift shafts get no door and are
filled with wall: closed blocks, not flyable inside. ``meta`` holds ``family: "floor"`` (which lets the plan
exceed the 21 × 11 m envelope, up to :data:`~edge_explorer.world.plan.FLOOR_FOOTPRINT_M`), ``shape``, ``ring``,
``seed``, the counts of rooms by kind (``offices``, ``labs``, ``lectures``, ``halls``, ``cores``) and ``generator``.

Splits: floor ``k`` of split ``s`` is named ``floor-<s>-<k:05d>`` and drawn from a seed derived from
(dataset seed, "floors", split, k) only (:func:`floor_seed`), independent of the 21 × 11 m dataset's seeds, so the
existing ``test`` split and the buildings A–D are unchanged. Sizes: :data:`FLOOR_SPLIT_SIZES`.

Usage::

    from edge_explorer.world.floors import generate_floor, regenerate_floor_split
    plan = generate_floor(7, "f")                      # one floor, deterministic in the seed
    test = regenerate_floor_split("test")              # the 32 test floors
    # catalog references: ``floors-test`` / ``floors-val`` (a whole split), ``floor-test-00003`` (one floor)
    # edge-explorer plans sheet --plans floors-test --png floors.png
    # edge-explorer plans check floor-test-00003

What a floor holds (aimed at real university and office floors, see the table): corridors 2.4–3.2 m; office rows
4.8–7 m deep, cut into offices 3.3–6 m wide (≈ 16–40 m²) with a few labs, lecture rooms and open-plan halls; deep
rows 10–18 m deep (60 % of rows; one spine row always holds offices), cut into open-plan halls 12–40 m wide, lecture
rooms 10–20 m and labs 8–16 m; on a ring floor an inner block 10–26 m deep whose segments are atria (one open hall),
one deep row or two rows back to back; a stairwell core every 25–50 m of corridor; doors 0.80–1.20 m (the
generator's); walls 0.10–0.15 m inside, 0.15–0.25 m outside; the spine 40–200 m long, drawn uniformly.

Measured with a one-off script (not in the repository) on the 32 test floors rasterized at 0.10 m (walls and tall
furniture as obstacles) and on 7 whole public KTH office floors, 206–271 m long (validation only, never
tuned to geometry; free = light pixels): ``width`` is the diameter of the largest free disc that covers a point (a
size spectrum of the free space that needs no room segmentation: the opening of the free space by discs of radius
0.75, 1.5, 2.5 and 4 m, via a distance transform), ``wall face`` the length of free/blocked cell edges per m² of
free floor. Version 1 is the first generator (office floors), version 2 this one::

    median [range]                     v1 (32)               v2 (32)               real KTH (7)
    long side [m]                      94 [41–188]           128 [54–193]          263 [205–270]
    free floor [m²]                    2,047 [440–5,552]     4,439 [1,101–11,731]  11,101 [6,006–21,538]
    free area, width < 1.5 m           0.03 [0.02–0.03]      0.01 [0.00–0.03]      0.03 [0.02–0.03]
                      1.5–3 m          0.32 [0.16–0.52]      0.13 [0.02–0.20]      0.04 [0.03–0.08]
                      3–5 m            0.48 [0.34–0.63]      0.19 [0.08–0.46]      0.16 [0.10–0.28]
                      5–8 m            0.15 [0.00–0.45]      0.16 [0.06–0.33]      0.18 [0.13–0.25]
                      ≥ 8 m            0.00 [0.00–0.25]      0.53 [0.16–0.69]      0.60 [0.48–0.65]
    wall face [m per m² free]          0.84 [0.72–0.91]      0.46 [0.36–0.64]      0.52 [0.46–0.58]
    rooms per 100 m² (segm., *)        3.8 [2.8–6.6]         1.1 [0.6–2.0]         0.6 [0.6–0.8]
    room area median [m²] (segm., *)   18 [13–28]            30 [21–94]            41 [20–52]
    corridor width [m] (segm., *)      2.0 [1.8–4.4]         2.6 [2.2–3.0]         3.2 [2.6–4.2]

(*) rooms: the components of the points at least 0.9 m from any obstacle (doorways of ≤ 1.2 m cut them apart),
each free cell given to its nearest component; corridor width: the median disc diameter on the ridge (local maxima
of the distance transform, 1.8–5 m wide) of the component with most such ridge cells. The real drawings have wide
gaps in their walls, so their rooms merge: their room figures are upper bounds on room size (lower bounds on room
count). What remains: v2 floors are shorter (the issue asks 40–200 m, the KTH floors are 205–270 m), still have
more 1.5–3 m space (corridors and small offices) and more, smaller rooms than the KTH university floors.

Timing (one core, shared machine): a floor takes 0.03–0.6 s (median 0.14 s) to generate, validate, rasterize at
0.05 m and check for connectivity (``floors-test``: 32 floors in about 6 s). Cutting a floor to its flight space
(what the catalog, ``plans check`` and N_M do) is the slow part: seconds for the 67 m ``floor-test-00012``, minutes
for a 150 m floor (``plans check`` on a 266 m KTH floor took 4 min 17 s).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from edge_explorer.errors import EdgeExplorerError, PlanError
from edge_explorer.world.floor_layouts import FloorConfig, floor_layout
from edge_explorer.world.generator import _furnish, _geometry, _m, _place_doors, _symmetry, checked_build
from edge_explorer.world.layouts import UNIT_M, Box, uniform_u
from edge_explorer.world.plan import FloorPlan, Furniture, Rect
from edge_explorer.world.raster import PlanRaster

FLOOR_GENERATOR_VERSION = 2  # bump whenever the same seed would give a different floor
MAX_ATTEMPTS = 8
SPLITS: tuple[str, ...] = ("train", "val", "test")
FLOOR_SPLIT_SIZES: dict[str, int] = {"train": 2000, "val": 100, "test": 32}
_FAMILY_SALT = 0xF1002  # keeps floor seeds apart from the 21 × 11 m dataset's plan_seed

# furniture per room kind: (m² of free floor per item, most items)
_FURNITURE: dict[str, tuple[float, int]] = {"room": (2.5, 6), "lab": (4.0, 12), "lecture": (6.0, 8), "hall": (8.0, 10)}


def floor_seed(dataset_seed: int, split: str, index: int) -> int:
    """The generator seed of floor ``index`` of ``split``."""
    if split not in SPLITS:
        raise EdgeExplorerError(f"unknown floor split {split!r}; choose one of {SPLITS}")
    state = np.random.SeedSequence([dataset_seed, _FAMILY_SALT, SPLITS.index(split), index]).generate_state(2)
    return int(state[0]) << 32 | int(state[1])


def floor_name(split: str, index: int) -> str:
    return f"floor-{split}-{index:05d}"


def _build(rng: np.random.Generator, cfg: FloorConfig, seed: int, name: str) -> FloorPlan:
    lay, shape, ring = floor_layout(rng, cfg)
    t_int = int(rng.integers(2, 4))  # 0.10 or 0.15 m
    t_ext = int(rng.integers(3, 6))  # 0.15 – 0.25 m
    geo = _geometry(lay, t_int, t_ext)
    shafts = frozenset(lb for lb, kind in enumerate(lay.kinds) if kind == "shaft")
    doors, doors_of = _place_doors(rng, lay, geo, t_int, shafts)
    walls: list[Box] = geo.walls + [geo.room_boxes[lb] for lb in sorted(shafts)]
    furniture: list[tuple[Box, float]] = []
    for label, box in geo.room_boxes.items():
        per_item, most = _FURNITURE.get(lay.kinds[label], (0.0, 0))
        area_m2 = (box[2] - box[0]) * (box[3] - box[1]) * UNIT_M**2
        cap = min(most, int(area_m2 / per_item)) if per_item else 0
        if cap > 0:
            furniture += _furnish(rng, box, doors_of[label], int(rng.integers(0, cap + 1)))
    sym = _symmetry(int(rng.integers(8)), lay.w, lay.h)

    def to_rect(b: Box) -> Rect:
        (ax, ay), (bx, by) = sym(b[0], b[1]), sym(b[2], b[3])
        return Rect(_m(min(ax, bx)), _m(min(ay, by)), _m(max(ax, bx)), _m(max(ay, by)))

    pts = [sym(x, y) for x, y in geo.outline]
    area2 = sum(pts[k - 1][0] * pts[k][1] - pts[k][0] * pts[k - 1][1] for k in range(len(pts)))
    if area2 < 0:
        pts.reverse()
    k0 = min(range(len(pts)), key=lambda k: (pts[k][1], pts[k][0]))
    counts = Counter(lay.kinds[1:])
    return FloorPlan(
        name=name,
        outline=tuple((_m(x), _m(y)) for x, y in pts[k0:] + pts[:k0]),
        walls=tuple(to_rect(b) for b in walls),
        doors=tuple(to_rect(b) for b in doors),
        furniture=tuple(Furniture(to_rect(b), hgt) for b, hgt in furniture),
        ceiling_height_m=_m(uniform_u(rng, 2.7, 3.4)),
        meta={
            "family": "floor",
            "shape": shape,
            "ring": ring,
            "seed": seed,
            "rooms": sum(n for k, n in counts.items() if k not in ("corridor", "shaft")),
            "offices": counts["room"],
            "labs": counts["lab"],
            "lectures": counts["lecture"],
            "halls": counts["hall"],
            "cores": counts["core"],
            "generator": FLOOR_GENERATOR_VERSION,
        },
    )


def generate_floor_and_raster(seed: int, name: str, cfg: FloorConfig | None = None) -> tuple[FloorPlan, PlanRaster]:
    """Like :func:`generate_floor`, also returning the 0.05 m raster that passed the connectivity check."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    cfg = cfg or FloorConfig()
    chosen = cfg
    return checked_build(
        lambda rng: _build(rng, chosen, seed, name),
        lambda attempt: [seed, 0xF1002] if attempt == 0 else [seed, 0xF1002, attempt],
        f"seed {seed}: no valid floor",
        MAX_ATTEMPTS,
    )


def generate_floor(seed: int, name: str, cfg: FloorConfig | None = None) -> FloorPlan:
    """One whole office floor, deterministic given ``(seed, cfg)``; valid and connected at the robot's radius.

    Raises :class:`PlanError` naming the seed if no valid floor came out of :data:`MAX_ATTEMPTS` attempts."""
    return generate_floor_and_raster(seed, name, cfg)[0]


def floor_of_split(split: str, index: int, dataset_seed: int = 0) -> FloorPlan:
    """Floor ``index`` of ``split`` (named ``floor-<split>-<index:05d>``)."""
    return generate_floor(floor_seed(dataset_seed, split, index), floor_name(split, index))


def regenerate_floor_split(split: str, count: int | None = None, dataset_seed: int = 0) -> list[FloorPlan]:
    """The floors of a split (its :data:`FLOOR_SPLIT_SIZES` size by default), skipping seeds that fail."""
    n = FLOOR_SPLIT_SIZES[split] if count is None and split in FLOOR_SPLIT_SIZES else count
    floor_seed(dataset_seed, split, 0)  # names the bad split
    out = []
    for k in range(n or 0):
        try:
            out.append(floor_of_split(split, k, dataset_seed))
        except PlanError:
            continue
    return out


def resolve_floor_reference(ref: str) -> list[FloorPlan] | None:
    """The floors a catalog reference names — ``floors-test`` / ``floors-val`` (the whole split) or
    ``floor-<split>-<k>`` (one floor) — or ``None`` when ``ref`` is not a floor reference."""
    if ref in ("floors-test", "floors-val"):
        return regenerate_floor_split(ref.split("-", 1)[1])
    parts = ref.split("-")
    if len(parts) == 3 and parts[0] == "floor" and parts[1] in SPLITS and parts[2].isdigit():
        return [floor_of_split(parts[1], int(parts[2]))]
    return None
