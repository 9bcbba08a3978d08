"""Loader for ROS map_server maps (YAML + PGM/PNG), the format external floor plans arrive in (docs/design.md §4).

Pixel → state follows map_server's "trinary" mode: p = (255 − v)/255 (or v/255 when ``negate: 1``);
occupied if p > occupied_thresh, free if p < free_thresh, unknown otherwise. Unknown pixels are treated as solid
(they are unmapped structure in a floor plan). The image's first row is the top of the map (largest y).

Interior: everything not reachable from the image border through free space, then cut to the flight space
(:func:`~edge_explorer.world.flight_space.restrict_to_flight_space`). A real floor plan often contains closed rooms
(no door drawn), slivers between two wall lines and thick walls; no flight can see into those, so they are dropped
from the interior (reported in ``LoadedMap.space``). This keeps N_M honest: a coverage goal of 95 % must be
reachable.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from edge_explorer.errors import PlanError
from edge_explorer.world.flight_space import FlightSpace, restrict_to_flight_space
from edge_explorer.world.grid import HIGH_RES_M, GridSpec
from edge_explorer.world.plan import DEFAULT_CEILING_M
from edge_explorer.world.raster import GRID_MARGIN_M, PlanRaster, interior_from_occupancy

REQUIRED_KEYS = ("image", "resolution", "origin")


@dataclass(frozen=True)
class LoadedMap:
    raster: PlanRaster  # at 0.05 m, its interior cut to the flight space (N_M counts what a flight can observe)
    space: FlightSpace  # what was kept and dropped, and why

    @property
    def dropped_free_area_m2(self) -> float:
        """Free floor no flight can reach or see (closed rooms, slivers between wall lines), in m²."""
        return self.space.dropped_free_m2


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise PlanError(f"{path}: cannot read map YAML ({exc.strerror})") from exc
    except yaml.YAMLError as exc:
        raise PlanError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict):
        raise PlanError(f"{path}: a map_server YAML must be a mapping with keys {list(REQUIRED_KEYS)}")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise PlanError(f"{path}: missing key(s) {missing} (map_server needs image, resolution, origin)")
    return data


def _number(data: dict[str, Any], key: str, default: float, path: Path) -> float:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise PlanError(f"{path}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def load_map_server(yaml_path: str | Path) -> LoadedMap:
    """Load a map_server map as a :class:`PlanRaster` at 0.05 m (nearest-neighbour resampled if the map's own
    resolution differs), its interior cut to the flight space (:mod:`edge_explorer.world.flight_space`).

    Raises :class:`PlanError` naming the file for a missing image, a non-positive resolution, a rotated origin,
    bad thresholds, or a map with no navigable interior.
    """
    path = Path(yaml_path)
    data = _read_yaml(path)
    resolution = _number(data, "resolution", 0.0, path)
    if resolution <= 0:
        raise PlanError(f"{path}: resolution must be positive, got {resolution}")
    origin = data["origin"]
    if not isinstance(origin, (list, tuple)) or len(origin) != 3:
        raise PlanError(f"{path}: origin must be [x, y, yaw], got {origin!r}")
    if abs(float(origin[2])) > 1e-9:
        raise PlanError(f"{path}: rotated origins (yaw {origin[2]}) are not supported; rotate the image instead")
    occ_t = _number(data, "occupied_thresh", 0.65, path)
    free_t = _number(data, "free_thresh", 0.196, path)
    if not (0 <= free_t < occ_t <= 1):
        raise PlanError(f"{path}: need 0 ≤ free_thresh < occupied_thresh ≤ 1, got {free_t}, {occ_t}")
    image_path = (path.parent / str(data["image"])).resolve()
    if not image_path.is_file():
        raise PlanError(f"{path}: image {str(data['image'])!r} not found at {image_path}")
    image = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
    if image is None or image.size == 0:
        raise PlanError(f"{path}: image {image_path} could not be decoded (expect 8-bit PGM or PNG)")

    value = image.astype(np.float32) / 255.0
    p_occ = value if int(data.get("negate", 0)) else 1.0 - value
    free_px = np.flipud(p_occ < free_t)  # flip: row 0 at the smallest y

    margin = int(round(GRID_MARGIN_M / resolution))
    free = np.pad(free_px, margin, constant_values=True)
    solid = ~free
    grid = GridSpec(
        (float(origin[0]) - margin * resolution, float(origin[1]) - margin * resolution),
        resolution,
        free.shape,
    )
    height = np.where(solid, DEFAULT_CEILING_M, 0.0).astype(np.float32)
    name = path.stem
    interior = interior_from_occupancy(solid)
    raster = PlanRaster(name, grid, height, interior, DEFAULT_CEILING_M)

    if abs(resolution - HIGH_RES_M) > 1e-9:
        raster = _resample(raster, HIGH_RES_M)
    kept, space = restrict_to_flight_space(raster)
    return LoadedMap(kept, space)


def _resample(raster: PlanRaster, resolution_m: float) -> PlanRaster:
    """Nearest-neighbour resampling of a map_server raster to the working resolution."""
    scale = raster.grid.resolution_m / resolution_m
    rows, cols = (int(round(n * scale)) for n in raster.grid.shape)
    size = (cols, rows)
    height = cv2.resize(raster.height_m, size, interpolation=cv2.INTER_NEAREST)
    interior = cv2.resize(raster.interior.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
    grid = GridSpec(raster.grid.origin_xy, resolution_m, (rows, cols))
    return PlanRaster(raster.name, grid, height, interior, raster.ceiling_height_m)
