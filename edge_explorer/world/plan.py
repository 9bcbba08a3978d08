"""The vector floor plan: the resolution-independent source of truth (docs/design.md §4).

JSON format (``format: "edge-explorer/floorplan"``, ``version: 1``), all lengths in metres, ``map`` frame::

    {
      "format": "edge-explorer/floorplan", "version": 1,
      "name": "A",
      "ceiling_height_m": 3.0,
      "outline":   [[x, y], ...],                     # building interior polygon, outer face of the perimeter walls
      "walls":     [[x_min, y_min, x_max, y_max], ...],   # axis-aligned wall boxes, full height (to the ceiling)
      "doors":     [[x_min, y_min, x_max, y_max], ...],   # open doorways carved out of the walls they cross
      "furniture": [[x_min, y_min, x_max, y_max, height_m], ...],  # boxes; height ≥ 1.5 m is "tall" (in the 2-D plan)
      "meta":      {"style": "corridor", "rooms": 7, "seed": 123}  # free-form, informational only
    }

A door's width is its extent along the wall it crosses (the longer side of its box) and must be ≥ 0.80 m.
The footprint must fit the paper's 21 m × 11 m envelope, or :data:`FLOOR_FOOTPRINT_M` for a whole office floor
(``meta.family == "floor"``, drawn by :mod:`edge_explorer.world.floors`); ``meta`` is otherwise informational.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edge_explorer.errors import PlanError

FORMAT_NAME = "edge-explorer/floorplan"
FORMAT_VERSION = 1

MAX_FOOTPRINT_M = (21.0, 11.0)  # long side, short side (the paper's envelope)
FLOOR_FOOTPRINT_M = (200.0, 120.0)  # long side, short side of a whole floor (meta "family": "floor")
MIN_DOOR_WIDTH_M = 0.80
TALL_HEIGHT_M = 1.5  # furniture at least this tall is part of the 2-D plan (flight height 1.7 m)
DEFAULT_CEILING_M = 3.0


@dataclass(frozen=True)
class Rect:
    """Axis-aligned box in the ``map`` frame."""

    x_min_m: float
    y_min_m: float
    x_max_m: float
    y_max_m: float

    @property
    def width_m(self) -> float:
        return self.x_max_m - self.x_min_m

    @property
    def height_m(self) -> float:
        return self.y_max_m - self.y_min_m

    def overlaps(self, other: Rect) -> bool:
        return (
            self.x_min_m < other.x_max_m
            and other.x_min_m < self.x_max_m
            and self.y_min_m < other.y_max_m
            and other.y_min_m < self.y_max_m
        )

    def as_list(self) -> list[float]:
        return [self.x_min_m, self.y_min_m, self.x_max_m, self.y_max_m]


@dataclass(frozen=True)
class Furniture:
    rect: Rect
    height_m: float

    @property
    def is_tall(self) -> bool:
        return self.height_m >= TALL_HEIGHT_M


@dataclass(frozen=True)
class FloorPlan:
    """A building: walls with doors, furniture, and the outline of its interior."""

    name: str
    outline: tuple[tuple[float, float], ...]
    walls: tuple[Rect, ...]
    doors: tuple[Rect, ...] = ()
    furniture: tuple[Furniture, ...] = ()
    ceiling_height_m: float = DEFAULT_CEILING_M
    meta: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def bounds(self) -> Rect:
        xs = [p[0] for p in self.outline]
        ys = [p[1] for p in self.outline]
        return Rect(min(xs), min(ys), max(xs), max(ys))

    # ---- JSON ---------------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "name": self.name,
            "ceiling_height_m": self.ceiling_height_m,
            "outline": [list(p) for p in self.outline],
            "walls": [w.as_list() for w in self.walls],
            "doors": [d.as_list() for d in self.doors],
            "furniture": [f.rect.as_list() + [f.height_m] for f in self.furniture],
            "meta": self.meta,
        }

    @staticmethod
    def from_dict(data: Any, source: str = "<plan>") -> FloorPlan:
        """Parse and validate; raises :class:`PlanError` naming ``source`` and the problem."""
        plan = _parse(data, source)
        validate_plan(plan, source)
        return plan


def load_plan_json(path: str | Path) -> FloorPlan:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise PlanError(f"{path}: cannot read plan file ({exc.strerror})") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PlanError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from exc
    return FloorPlan.from_dict(data, str(path))


def save_plan_json(plan: FloorPlan, path: str | Path) -> None:
    """Write the plan with one box per line (diff-friendly, compact)."""
    data = plan.to_dict()
    lines = [f'  "{k}": {json.dumps(v)}' for k, v in data.items() if not isinstance(v, list)]
    for key in ("outline", "walls", "doors", "furniture"):
        items = ",\n".join(f"    {json.dumps(item)}" for item in data[key])
        lines.append(f'  "{key}": [\n{items}\n  ]' if items else f'  "{key}": []')
    Path(path).write_text("{\n" + ",\n".join(lines) + "\n}\n")


def _numbers(value: Any, n: int, what: str, source: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise PlanError(f"{source}: {what} must be a list of {n} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise PlanError(f"{source}: {what} must hold finite numbers, got {value!r}")
        out.append(float(v))
    return out


def _rect(value: Any, what: str, source: str) -> Rect:
    x0, y0, x1, y1 = _numbers(value, 4, what, source)
    if not (x0 < x1 and y0 < y1):
        raise PlanError(f"{source}: {what} {value!r} must have x_min < x_max and y_min < y_max")
    return Rect(x0, y0, x1, y1)


def _parse(data: Any, source: str) -> FloorPlan:
    if not isinstance(data, dict):
        raise PlanError(f"{source}: a plan must be a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT_NAME:
        raise PlanError(f"{source}: 'format' must be {FORMAT_NAME!r}, got {data.get('format')!r}")
    if data.get("version") != FORMAT_VERSION:
        raise PlanError(
            f"{source}: unsupported plan version {data.get('version')!r} (this build reads {FORMAT_VERSION})"
        )
    known = {"format", "version", "name", "ceiling_height_m", "outline", "walls", "doors", "furniture", "meta"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise PlanError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(known)}")
    for key in ("name", "outline", "walls"):
        if key not in data:
            raise PlanError(f"{source}: missing required key {key!r}")
    if not isinstance(data["name"], str) or not data["name"]:
        raise PlanError(f"{source}: 'name' must be a non-empty string")
    for key in ("outline", "walls", "doors", "furniture"):
        if not isinstance(data.get(key, []), list):
            raise PlanError(f"{source}: {key!r} must be a list")
    outline = tuple(tuple(_numbers(p, 2, f"outline[{k}]", source)) for k, p in enumerate(data["outline"]))
    walls = tuple(_rect(w, f"walls[{k}]", source) for k, w in enumerate(data["walls"]))
    doors = tuple(_rect(d, f"doors[{k}]", source) for k, d in enumerate(data.get("doors", [])))
    furniture = []
    for k, f in enumerate(data.get("furniture", [])):
        x0, y0, x1, y1, h = _numbers(f, 5, f"furniture[{k}]", source)
        furniture.append(Furniture(_rect([x0, y0, x1, y1], f"furniture[{k}]", source), h))
    ceiling = _numbers([data.get("ceiling_height_m", DEFAULT_CEILING_M)], 1, "ceiling_height_m", source)[0]
    meta = data.get("meta", {})
    if not isinstance(meta, dict):
        raise PlanError(f"{source}: 'meta' must be an object")
    return FloorPlan(data["name"], outline, walls, doors, tuple(furniture), ceiling, meta)  # type: ignore[arg-type]


def validate_plan(plan: FloorPlan, source: str | None = None) -> None:
    """Geometric rules of the dataset that need no rasterization (docs/design.md §4).

    Connectivity at the robot radius needs a raster: see :func:`edge_explorer.world.raster.check_connected`.
    """
    src = source or plan.name
    if len(plan.outline) < 4:
        raise PlanError(f"{src}: outline needs at least 4 vertices, got {len(plan.outline)}")
    n = len(plan.outline)
    for k in range(n):
        (xa, ya), (xb, yb) = plan.outline[k], plan.outline[(k + 1) % n]
        if (xa != xb) == (ya != yb):
            raise PlanError(
                f"{src}: outline edge {k} from {(xa, ya)} to {(xb, yb)} is not axis-aligned (walls are perpendicular)"
            )
    b = plan.bounds()
    long_side, short_side = max(b.width_m, b.height_m), min(b.width_m, b.height_m)
    envelope = FLOOR_FOOTPRINT_M if plan.meta.get("family") == "floor" else MAX_FOOTPRINT_M
    if long_side > envelope[0] + 1e-6 or short_side > envelope[1] + 1e-6:
        raise PlanError(
            f"{src}: footprint {b.width_m:.2f} m × {b.height_m:.2f} m exceeds the "
            f"{envelope[0]:g} m × {envelope[1]:g} m envelope"
        )
    if not plan.walls:
        raise PlanError(f"{src}: a plan needs walls")
    if not (plan.ceiling_height_m > TALL_HEIGHT_M):
        raise PlanError(f"{src}: ceiling_height_m must exceed {TALL_HEIGHT_M} m, got {plan.ceiling_height_m}")
    tol = 1e-6
    for k, w in enumerate(plan.walls):
        if (
            w.x_min_m < b.x_min_m - tol
            or w.x_max_m > b.x_max_m + tol
            or w.y_min_m < b.y_min_m - tol
            or w.y_max_m > b.y_max_m + tol
        ):
            raise PlanError(f"{src}: walls[{k}] {w.as_list()} lies outside the outline's bounds {b.as_list()}")
    for k, d in enumerate(plan.doors):
        width = max(d.width_m, d.height_m)
        if width < MIN_DOOR_WIDTH_M - tol:
            raise PlanError(f"{src}: doors[{k}] is {width:.2f} m wide; doors must be at least {MIN_DOOR_WIDTH_M} m")
        if not any(d.overlaps(w) for w in plan.walls):
            raise PlanError(f"{src}: doors[{k}] {d.as_list()} does not cross any wall")
    for k, f in enumerate(plan.furniture):
        if not (0 < f.height_m <= plan.ceiling_height_m):
            raise PlanError(
                f"{src}: furniture[{k}] height {f.height_m} m must be in (0, ceiling {plan.ceiling_height_m} m]"
            )
