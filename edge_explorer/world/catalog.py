"""Finding buildings by name: bundled plans, plan files, map_server maps, folders and regenerated splits.

Every loader returns :class:`PlanRaster` at the high resolution (0.05 m), the currency of every later stage.
References (comma-separated lists allowed):

* ``A`` … ``D`` — the bundled benchmark buildings (``edge_explorer/data/plans``);
* ``test`` — the 100-plan test split, regenerated deterministically (:mod:`edge_explorer.world.dataset`);
* ``path/plan.json`` — a vector plan; ``path/map.yaml`` — a ROS map_server map;
* a folder — every ``*.json`` / ``*.yaml`` in it, or the plans in its ``*.jsonl.gz`` shards.
"""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from edge_explorer.errors import PlanError
from edge_explorer.world.grid import HIGH_RES_M, GridSpec
from edge_explorer.world.mapserver import load_map_server
from edge_explorer.world.plan import FloorPlan, load_plan_json
from edge_explorer.world.raster import PlanRaster, check_connected, rasterize

log = logging.getLogger(__name__)

BUNDLED_NAMES: tuple[str, ...] = ("A", "B", "C", "D")


def bundled_plan_path(name: str) -> Path:
    return Path(str(resources.files("edge_explorer") / "data" / "plans" / f"{name}.json"))


def plan_to_raster(plan: FloorPlan, resolution_m: float = HIGH_RES_M) -> PlanRaster:
    """Rasterize a vector plan and enforce the robot-radius connectivity rule."""
    raster = rasterize(plan, resolution_m)
    check_connected(raster)
    return raster


def _resample(raster: PlanRaster, resolution_m: float) -> PlanRaster:
    """Nearest-neighbour resampling of a map_server raster to the working resolution."""
    scale = raster.grid.resolution_m / resolution_m
    rows, cols = (int(round(n * scale)) for n in raster.grid.shape)
    size = (cols, rows)
    height = cv2.resize(raster.height_m, size, interpolation=cv2.INTER_NEAREST)
    interior = cv2.resize(raster.interior.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
    grid = GridSpec(raster.grid.origin_xy, resolution_m, (rows, cols))
    return PlanRaster(raster.name, grid, height, interior, raster.ceiling_height_m)


def load_map_yaml(path: Path) -> PlanRaster:
    loaded = load_map_server(path)
    if loaded.dropped_free_area_m2 > 0:
        log.info("%s: dropped %.1f m² of free space the robot cannot reach", path, loaded.dropped_free_area_m2)
    raster = loaded.raster
    if abs(raster.grid.resolution_m - HIGH_RES_M) > 1e-9:
        raster = _resample(raster, HIGH_RES_M)
    return raster


def _load_path(path: Path) -> list[PlanRaster]:
    if path.is_dir():
        from edge_explorer.world.dataset import iter_shard_plans

        shards = sorted(path.rglob("*.jsonl.gz"))
        if shards:
            return [plan_to_raster(p) for p in iter_shard_plans(shards)]
        files = sorted(p for p in path.iterdir() if p.suffix in (".json", ".yaml", ".yml"))
        if not files:
            raise PlanError(f"{path}: folder holds no plans (*.json, *.yaml or *.jsonl.gz shards)")
        return [r for f in files for r in _load_path(f)]
    if path.suffix == ".json":
        return [plan_to_raster(load_plan_json(path))]
    if path.suffix in (".yaml", ".yml"):
        return [load_map_yaml(path)]
    if not path.exists():
        raise PlanError(f"{path}: no such plan; use A-D, 'test', a .json plan, a map_server .yaml, or a folder")
    raise PlanError(f"{path}: unknown plan file type {path.suffix!r}; expected .json or .yaml")


def load_buildings(ref: str) -> list[PlanRaster]:
    """Resolve a plan reference (see module docstring) to rasters at 0.05 m."""
    out: list[PlanRaster] = []
    for part in (p.strip() for p in ref.split(",")):
        if not part:
            raise PlanError(f"empty plan name in {ref!r}")
        if part in BUNDLED_NAMES:
            out.append(plan_to_raster(load_plan_json(bundled_plan_path(part))))
        elif part == "test":
            from edge_explorer.world.dataset import regenerate_split

            out.extend(plan_to_raster(p) for p in regenerate_split("test"))
        else:
            out.extend(_load_path(Path(part)))
    return out


def load_building(ref: str) -> PlanRaster:
    """Exactly one building; raises :class:`PlanError` if ``ref`` names several."""
    rasters = load_buildings(ref)
    if len(rasters) != 1:
        raise PlanError(f"{ref!r} names {len(rasters)} plans where one is expected")
    return rasters[0]
