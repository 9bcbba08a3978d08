"""What the daemon's parts share, as two small explicit objects handed to those that need them.

:class:`FlightState` is where the flight stands: its phase, home, the stop reason and the ending. The flight phases
move it along; the input watchdog sets the stop reason when a pilot takes over; the decision pipeline reads the
phase (through the phases); the daemon reads it to end its loop and moves home after a pose jump.

:class:`FlightMaps` is the world as flown: the 0.05 m and 0.20 m voxel maps and the flown footprint (see the package
docstring, "Flown space is free"), growing as the vehicle observes (:mod:`edge_explorer.mapping.growing`). The
phases start them at take-off, the watchdog fuses frames into them and stamps the footprint, the daemon starts them
afresh after a pose jump, the decision pipeline projects them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_explorer.mapping.growing import GrowingMaps, GrowthConfig
from edge_explorer.mapping.projection import HeightBand
from edge_explorer.mapping.voxels import FusionConfig, VoxelRegion
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.world.grid import GridSpec

PHASES: tuple[str, ...] = ("takeoff", "exploring", "returning", "home", "done")


@dataclass
class FlightState:
    """Where the flight stands. ``phase``: takeoff → exploring → returning → home → done; ``home_xy``: the take-off
    point (moved with the maps' frame after a pose jump); ``stop_reason``: set when the run must end at the next loop
    iteration; ``ending``: why exploration (or the run) ended, for the report; ``reached_home``: the return ended
    within :data:`~edge_explorer.runtime.daemon.phases.HOME_REACHED_M` of home (not by its time limit, nor at the
    nearest point of the observed map that the vehicle could reach)."""

    phase: str = "takeoff"
    home_xy: tuple[float, float] | None = None
    stop_reason: str | None = None
    ending: str | None = None
    reached_home: bool = False

    def move_home(self, dx_m: float, dy_m: float) -> None:
        """Home in a map frame shifted by (``dx_m``, ``dy_m``) (after an odometry jump); nothing before take-off."""
        if self.home_xy is not None:
            self.home_xy = (self.home_xy[0] + dx_m, self.home_xy[1] + dy_m)


class FlightMaps:
    """The maps of one flight (:class:`~edge_explorer.mapping.growing.GrowingMaps`: the voxel maps and the flown
    footprint); None before take-off.

    They start as a small box around the take-off point and grow as the vehicle observes: nothing here is sized
    from a plan (a plan only scores coverage)."""

    def __init__(self, fusion: FusionConfig, growth: GrowthConfig | None = None) -> None:
        self.fusion = fusion
        self.growth = growth if growth is not None else GrowthConfig()
        self.voxels: GrowingMaps | None = None
        self._start: tuple[float, float, HeightBand] | None = None

    @property
    def region(self) -> VoxelRegion | None:
        """The 0.20 m map's box now (it grows); None before take-off."""
        return None if self.voxels is None else self.voxels.region

    @property
    def flown_grid(self) -> GridSpec | None:
        return None if self.voxels is None else self.voxels.grid

    @property
    def flown(self) -> np.ndarray | None:
        """uint8 on :attr:`flown_grid`: 1 where the vehicle's body has been."""
        return None if self.voxels is None else self.voxels.flown

    def start(self, x_m: float, y_m: float, band: HeightBand) -> None:
        """Empty maps for a take-off at (``x_m``, ``y_m``), projected over ``band``."""
        self._start = (x_m, y_m, band)
        self.reset()

    def reset(self) -> None:
        """Empty maps around the take-off point, and no flown footprint (after a pose jump: they grow from there)."""
        assert self._start is not None
        x_m, y_m, band = self._start
        self.voxels = GrowingMaps(x_m, y_m, band_z_range_m(band), self.fusion, self.growth, band)

    def mark_flown(self, x_m: float, y_m: float, radius_m: float) -> None:
        """Every high-res cell within ``radius_m`` of (``x_m``, ``y_m``) has been flown through."""
        assert self.voxels is not None
        self.voxels.mark_flown(x_m, y_m, radius_m)

    def project(self, band: HeightBand) -> tuple[np.ndarray, GridSpec, np.ndarray, GridSpec]:
        """Both maps projected over ``band`` (high codes, high grid, low codes, low grid) over everything seen, the
        flown footprint counted free on the high-res map where the sensor saw nothing."""
        assert self.voxels is not None
        if band != self.voxels.band:
            raise ValueError("the maps are projected over the band they were started with")
        return self.voxels.project()
