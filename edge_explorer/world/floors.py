"""Whole office floors of 40–200 m to learn from (issue #55): generator, train / val / test splits, references.

``generate_floor(seed, name)`` draws one floor with :func:`~edge_explorer.world.floor_layouts.floor_layout`
(corridor spines — straight, L, T, U, comb, H, or a ring around an inner block — wings, rows of offices, labs,
halls and stairwell cores) and builds it with the 21 × 11 m generator's own stages
(:mod:`edge_explorer.world.generator`): label grid → walls → doors on a spanning tree from the corridor (so every
room is reachable at the robot's radius) → furniture → a random symmetry → :func:`validate_plan` and the
connectivity check at 0.05 m; a failed attempt is retried with a derived seed. Lift shafts get no door and are
filled with wall: closed blocks, not flyable inside. ``meta`` holds ``family: "floor"`` (which lets the plan
exceed the 21 × 11 m envelope, up to :data:`~edge_explorer.world.plan.FLOOR_FOOTPRINT_M`), ``shape``, ``ring``,
``seed``, the counts of rooms by kind and ``generator``.

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

Statistics aimed for (office practice): corridors 1.8–2.6 m, office rows 4.2–6.5 m deep (labs 6.5–9 m), offices
2.6–4.6 m wide (≈ 11–30 m²), labs 6–12 m wide, halls 10–20 m, a stairwell core every 25–50 m of corridor, doors
0.80–1.20 m (the generator's), walls 0.10–0.15 m inside, 0.15–0.25 m outside.

Measured with a one-off script (not in the repository) on the 32 test floors rasterized at 0.10 m (walls and tall
furniture as obstacles) and on the 7 whole KTH floors of ``../shared/data/realplans_whole`` (validation only, never
tuned to): ``width`` is the diameter of the largest free disc that covers a point (a size spectrum of the free space
that needs no room segmentation), ``wall face`` the length of free-space boundary per m² of free floor::

                                       generated (32, median [range])   real KTH (7, median [range])
    long side [m]                      93 [41–188]                      263 [205–271]
    free floor [m²]                    2,050 [440–5,550]                11,200 [6,100–21,500]
    free area, width < 1.5 m           0.03 [0.02–0.03]                 0.03 [0.02–0.03]
                      1.5–3 m          0.32 [0.16–0.52]                 0.05 [0.03–0.08]
                      3–5 m            0.48 [0.34–0.63]                 0.16 [0.10–0.27]
                      5–8 m            0.15 [0.00–0.45]                 0.17 [0.13–0.25]
                      ≥ 8 m            0.00 [0.00–0.25]                 0.60 [0.48–0.65]
    wall face [m per m² free]          0.82 [0.70–0.89]                 0.46 [0.42–0.53]
    rooms per 100 m² (segmented, *)    4.6 [2.8–7.1]                    0.6 [0.5–0.7]
    room area median [m²] (segm., *)   16 [12–23]                       48 [22–52]
    corridor width [m] (segm., *)      2.2 [1.8–3.5]                    2.8 [2.0–3.2]

(*) doorways cut by an opening of 0.9 m radius; the real drawings have wide gaps in their walls, so their rooms merge
and these real figures are upper bounds on room size (lower bounds on room count). The gap is real all the same:
the KTH floors (university buildings) hold much more open space — halls, lecture rooms, atria wider than 8 m —
than these office floors, whose free space is mostly corridors and cellular offices. Raising ``p_hall``,
``hall_width_m`` and ``p_lab`` in :class:`FloorConfig` moves the spectrum towards them.

Timing (one core, shared machine): a floor takes 0.1–0.6 s to generate, validate, rasterize at 0.05 m and check
for connectivity (``floors-test``: 32 floors in about 8 s, ``plans sheet --plans floors-test`` 8.5 s). Cutting a
floor to its flight space (what the catalog, ``plans check`` and N_M do) is the slow part: about 2 s for the 42 m
``floor-test-00006``, minutes for a 150 m floor (``plans check`` on a 266 m KTH floor took 4 min 17 s).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from edge_explorer.errors import EdgeExplorerError, PlanError
from edge_explorer.world.floor_layouts import FloorConfig, floor_layout
from edge_explorer.world.generator import _furnish, _geometry, _m, _place_doors, _symmetry
from edge_explorer.world.grid import HIGH_RES_M
from edge_explorer.world.layouts import UNIT_M, Box, Retry, uniform_u
from edge_explorer.world.plan import FloorPlan, Furniture, Rect, validate_plan
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, check_connected, rasterize

FLOOR_GENERATOR_VERSION = 1  # bump whenever the same seed would give a different floor
MAX_ATTEMPTS = 8
SPLITS: tuple[str, ...] = ("train", "val", "test")
FLOOR_SPLIT_SIZES: dict[str, int] = {"train": 2000, "val": 100, "test": 32}
_FAMILY_SALT = 0xF1002  # keeps floor seeds apart from the 21 × 11 m dataset's plan_seed

# furniture per room kind: (m² of free floor per item, most items)
_FURNITURE: dict[str, tuple[float, int]] = {"room": (2.5, 6), "lab": (4.0, 12), "hall": (8.0, 10)}


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
    problems = []
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([seed, 0xF1002] if attempt == 0 else [seed, 0xF1002, attempt])
        try:
            plan = _build(rng, cfg, seed, name)
            validate_plan(plan)
            raster = rasterize(plan, HIGH_RES_M)
            check_connected(raster, ROBOT_RADIUS_M)
        except (Retry, PlanError) as exc:
            problems.append(str(exc))
            continue
        return plan, raster
    raise PlanError(f"seed {seed}: no valid floor in {MAX_ATTEMPTS} attempts (last: {problems[-1]})")


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


def sheet_rasters(ref: str) -> tuple[list[PlanRaster], list[str]]:
    """Rasters and titles for ``plans sheet --plans REF`` (a comma-separated list): floors at 0.10 m, drawn without
    cutting them to the flight space (minutes per large floor); any other reference through the catalog."""
    from edge_explorer.world.catalog import load_buildings

    rasters: list[PlanRaster] = []
    titles: list[str] = []
    for part in (p.strip() for p in ref.split(",")):
        floors = resolve_floor_reference(part)
        if floors is None:
            loaded = load_buildings(part)
            rasters += loaded
            titles += [r.name for r in loaded]
            continue
        for p in floors:
            b = p.bounds()
            ring = " ring" if p.meta["ring"] else ""
            titles.append(
                f"{p.name} · {p.meta['shape']}{ring} · {b.width_m:.0f}×{b.height_m:.0f} m · {p.meta['rooms']} rooms"
            )
            rasters.append(rasterize(p, 0.10))
    return rasters, titles
