"""Finding buildings by name: bundled plans, plan files, map_server maps, folders and regenerated splits.

Every loader returns :class:`PlanRaster` at the high resolution (0.05 m), the currency of every later stage, its
interior cut to the flight space (:mod:`edge_explorer.world.flight_space`: N_M counts what a flight can observe).
References (comma-separated lists allowed):

* ``A`` … ``D`` — the bundled benchmark buildings (``edge_explorer/data/plans``);
* ``test`` — the 100-plan test split, regenerated deterministically (:mod:`edge_explorer.world.dataset`);
* ``floors-test``, ``floors-val`` — the whole office floors of a split, ``floor-test-00003`` — one of them
  (:mod:`edge_explorer.world.floors`; a floor of 100 m or more takes minutes to cut to its flight space);
* ``path/plan.json`` — a vector plan; ``path/map.yaml`` — a ROS map_server map;
* a folder — every ``*.json`` / ``*.yaml`` in it, or the plans in its ``*.jsonl.gz`` shards.
"""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path

from edge_explorer.errors import PlanError
from edge_explorer.world.flight_space import FlightSpace, restrict_to_flight_space
from edge_explorer.world.grid import HIGH_RES_M
from edge_explorer.world.mapserver import load_map_server
from edge_explorer.world.plan import FloorPlan, load_plan_json
from edge_explorer.world.raster import PlanRaster, check_connected, rasterize

log = logging.getLogger(__name__)

BUNDLED_NAMES: tuple[str, ...] = ("A", "B", "C", "D")


def bundled_plan_path(name: str) -> Path:
    return Path(str(resources.files("edge_explorer") / "data" / "plans" / f"{name}.json"))


def plan_to_raster(plan: FloorPlan) -> PlanRaster:
    """Rasterize a vector plan at 0.05 m, enforce the robot-radius connectivity rule and cut the interior to the
    flight space (N_M counts what a flight can observe: :mod:`edge_explorer.world.flight_space`)."""
    return _plan_with_space(plan)[0]


def _plan_with_space(plan: FloorPlan) -> tuple[PlanRaster, FlightSpace]:
    raster = rasterize(plan, HIGH_RES_M)
    check_connected(raster)
    return restrict_to_flight_space(raster)


def _map_with_space(path: Path) -> tuple[PlanRaster, FlightSpace]:
    loaded = load_map_server(path)
    space = loaded.space
    if space.dropped_free_m2 + space.dropped_wall_m2 > 0:
        log.info(
            "%s: N_M leaves out %.1f m² of floor and %.1f m² of wall no flight can reach or see",
            path,
            space.dropped_free_m2,
            space.dropped_wall_m2,
        )
    return loaded.raster, space


def _load_path(path: Path) -> list[tuple[PlanRaster, FlightSpace]]:
    if path.is_dir():
        from edge_explorer.world.dataset import iter_shard_plans

        shards = sorted(path.rglob("*.jsonl.gz"))
        if shards:
            return [_plan_with_space(p) for p in iter_shard_plans(shards)]
        files = sorted(p for p in path.iterdir() if p.suffix in (".json", ".yaml", ".yml"))
        if not files:
            raise PlanError(f"{path}: folder holds no plans (*.json, *.yaml or *.jsonl.gz shards)")
        return [r for f in files for r in _load_path(f)]
    if path.suffix == ".json":
        return [_plan_with_space(load_plan_json(path))]
    if path.suffix in (".yaml", ".yml"):
        return [_map_with_space(path)]
    if not path.exists():
        raise PlanError(
            f"{path}: no such plan; use A-D, 'test', 'floors-test', a .json plan, a map_server .yaml, or a folder"
        )
    raise PlanError(f"{path}: unknown plan file type {path.suffix!r}; expected .json or .yaml")


def _floors(ref: str) -> list[FloorPlan] | None:
    from edge_explorer.world.floors import resolve_floor_reference

    return resolve_floor_reference(ref)


def load_buildings_with_space(ref: str) -> list[tuple[PlanRaster, FlightSpace]]:
    """Resolve a plan reference (see module docstring) to rasters at 0.05 m, each with its flight space (what N_M
    kept and dropped)."""
    out: list[tuple[PlanRaster, FlightSpace]] = []
    for part in (p.strip() for p in ref.split(",")):
        if not part:
            raise PlanError(f"empty plan name in {ref!r}")
        if part in BUNDLED_NAMES:
            out.append(_plan_with_space(load_plan_json(bundled_plan_path(part))))
        elif part == "test":
            from edge_explorer.world.dataset import regenerate_split

            out.extend(_plan_with_space(p) for p in regenerate_split("test"))
        elif (floors := _floors(part)) is not None:
            out.extend(_plan_with_space(p) for p in floors)
        else:
            out.extend(_load_path(Path(part)))
    return out


def load_buildings(ref: str) -> list[PlanRaster]:
    """Resolve a plan reference (see module docstring) to rasters at 0.05 m."""
    return [raster for raster, _ in load_buildings_with_space(ref)]


def load_building(ref: str) -> PlanRaster:
    """Exactly one building; raises :class:`PlanError` if ``ref`` names several."""
    rasters = load_buildings(ref)
    if len(rasters) != 1:
        raise PlanError(f"{ref!r} names {len(rasters)} plans where one is expected")
    return rasters[0]


def floor_rasters(split: str, first: int, stop: int) -> list[PlanRaster]:
    """Whole floors [first, stop) of a floor split (``floor-<split>-<k>``), cut to their flight space as the bench
    flies them: the training data of the goal policy and the predictor on whole floors. A seed the generator gives up
    on is skipped, as :func:`~edge_explorer.world.floors.regenerate_floor_split` skips it."""
    from edge_explorer.world.floors import floor_name

    rasters = []
    for k in range(first, stop):
        try:
            rasters += load_buildings(floor_name(split, k))
        except PlanError:
            continue
    return rasters


def sheet_rasters(ref: str) -> tuple[list[PlanRaster], list[str]]:
    """Rasters and titles for ``plans sheet --plans REF`` (a comma-separated list): floors at 0.10 m, drawn without
    cutting them to the flight space (minutes per large floor); any other reference through the catalog."""
    from edge_explorer.world.floors import resolve_floor_reference

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
