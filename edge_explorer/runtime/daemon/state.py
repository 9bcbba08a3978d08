"""What the daemon's parts share, as two small explicit objects handed to those that need them.

:class:`FlightState` is where the flight stands: its phase, home, the stop reason and the ending. The flight phases
move it along; the input watchdog sets the stop reason when a pilot takes over; the decision pipeline reads the
phase (through the phases); the daemon reads it to end its loop and moves home after a pose jump.

:class:`FlightMaps` is the world as flown: the 0.05 m and 0.20 m voxel maps and the flown footprint (see the package
docstring, "Flown space is free"). The phases start them at take-off, the watchdog fuses frames into them and stamps
the footprint, the daemon starts them afresh after a pose jump, the decision pipeline projects them."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.world.grid import FREE, UNKNOWN, GridSpec

PHASES: tuple[str, ...] = ("takeoff", "exploring", "returning", "home", "done")


@dataclass
class FlightState:
    """Where the flight stands. ``phase``: takeoff → exploring → returning → home → done; ``home_xy``: the take-off
    point (moved with the maps' frame after a pose jump); ``stop_reason``: set when the run must end at the next loop
    iteration; ``ending``: why exploration (or the run) ended, for the report."""

    phase: str = "takeoff"
    home_xy: tuple[float, float] | None = None
    stop_reason: str | None = None
    ending: str | None = None

    def move_home(self, dx_m: float, dy_m: float) -> None:
        """Home in a map frame shifted by (``dx_m``, ``dy_m``) (after an odometry jump); nothing before take-off."""
        if self.home_xy is not None:
            self.home_xy = (self.home_xy[0] + dx_m, self.home_xy[1] + dy_m)


class FlightMaps:
    """The voxel maps of one flight and the flown footprint on the high-res grid; None of them before take-off.

    ``region`` is the maps' box; when none is given, :meth:`start` centres a 24 m × 14 m box on the take-off point.
    """

    def __init__(self, fusion: FusionConfig, region: VoxelRegion | None = None) -> None:
        self.fusion = fusion
        self.region = region
        self.voxels: VoxelMaps | None = None
        self.flown_grid: GridSpec | None = None
        self.flown: np.ndarray | None = None  # uint8 on flown_grid: 1 where the vehicle's body has been

    def start(self, x_m: float, y_m: float, band: HeightBand) -> None:
        """Empty maps for a take-off at (``x_m``, ``y_m``): over ``region``, or a box around the point."""
        if self.region is None:
            z_min_m, z_max_m = band_z_range_m(band)
            self.region = VoxelRegion((x_m - 12.0, y_m - 7.0, z_min_m), (24.0, 14.0, z_max_m - z_min_m))
        self.reset()

    def reset(self) -> None:
        """Empty voxel maps over the region, and no flown footprint."""
        assert self.region is not None
        self.voxels = VoxelMaps(self.region, self.fusion)
        self.flown_grid = self.voxels.high.grid
        self.flown = np.zeros(self.flown_grid.shape, dtype=np.uint8)

    def mark_flown(self, x_m: float, y_m: float, radius_m: float) -> None:
        """Every high-res cell within ``radius_m`` of (``x_m``, ``y_m``) has been flown through."""
        assert self.flown is not None and self.flown_grid is not None
        radius_cells = int(radius_m / self.flown_grid.resolution_m)
        if radius_cells <= 0:
            return
        row, col = self.flown_grid.cell_of(x_m, y_m)
        cv2.circle(self.flown, (int(col), int(row)), radius_cells, 1, thickness=-1)

    def project(self, band: HeightBand) -> tuple[np.ndarray, GridSpec, np.ndarray, GridSpec]:
        """Both maps projected over ``band`` (high codes, high grid, low codes, low grid), the flown footprint
        counted free on the high-res map where the sensor saw nothing."""
        assert self.voxels is not None and self.flown is not None
        high, high_grid = project(self.voxels.high, band)
        high[(self.flown != 0) & (high == UNKNOWN)] = FREE
        low, low_grid = project(self.voxels.low, band)
        return high, high_grid, low, low_grid
