"""How the daemon flies and when it stops (:class:`DaemonConfig`), the autopilot modes it flies in, and the height
its voxel maps cover (:func:`band_z_range_m`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from edge_explorer.mapping.growing import GrowthConfig
from edge_explorer.mapping.projection import HeightBand
from edge_explorer.mapping.voxels import FusionConfig
from edge_explorer.plan.follow import FollowConfig
from edge_explorer.plan.registry import PLANNERS
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.predict.verification import DEFAULT_STOP_THRESHOLD_M2
from edge_explorer.runtime.mavlink_link import PX4_OFFBOARD_MODE
from edge_explorer.world.grid import LOW_RES_M

AUTOPILOT_MODES = {"px4": PX4_OFFBOARD_MODE, "ardupilot": "GUIDED"}
# A mode change this soon after our setpoint stream stalled is the autopilot's reaction to the stall, not a pilot's.
STALL_BLAME_S = 3.0


@dataclass(frozen=True)
class DaemonConfig:
    """How the daemon flies and when it stops. Times in seconds, distances in metres (map frame)."""

    coverage_goal: float = 0.95
    # The flight budget after take-off (a battery's worth): exploration ends early enough that the way home fits in
    # it — the reserve is the path home over the observed map (measured every home_path_every_s, plus the straight
    # line flown since) × home_path_slack at cruise speed, plus the hover at home and home_reserve_margin_s; before
    # the first measurement, the straight line home × home_detour_factor. The demo on building A reaches 95 % in
    # ~5 min. On a 271 m floor the way home was 1.0–2.3 × the straight line and took 2.06–2.11 s per metre of it at
    # 0.5 m/s cruise (3 flights, session 44): the straight line × 2 left one flight 12 s late.
    time_limit_s: float = 600.0
    home_detour_factor: float = 2.0  # paths home through doors and corridors run longer than the straight line
    home_path_slack: float = 1.15  # the flown way home is longer and slower than the graph's path (turns, pursuit)
    home_path_every_s: float = 10.0  # the path home is measured this often while exploring (~0.2 s on 271 m)
    home_reserve_margin_s: float = 10.0
    return_home: bool = True
    home_hover_s: float = 2.0
    return_time_limit_s: float = 180.0  # or twice the reserve at the end of exploration, where that is longer
    flight_height_m: float = HeightBand().flight_z_m
    takeoff_speed_mps: float = 0.5  # average climb speed (the min-jerk peak is 1.875× that)
    autopilot: str = "px4"  # start sequence: "px4" (OFFBOARD) or "ardupilot" (GUIDED + take-off)
    offboard_warmup_s: float = 1.0
    setpoint_rate_hz: float = 20.0
    decision_lead_s: float = 1.0 / 15.0  # decide on the last frame before the reference reaches its waypoint
    odometry_max_age_s: float = 0.3
    pose_jump_m: float = 1.0
    jump_settle_s: float = 1.0
    depth_timeout_s: float = 1.0
    max_hold_s: float = 60.0  # inputs not back after this long: end the flight (the autopilot's failsafe takes over)
    reanchor_distance_m: float = 0.5
    footprint_clear_m: float = 0.2  # flown space counted as free (below the 0.25 m robot radius; 0 disables)
    # The goal planner that explores without a learned policy (and takes over from one that fails): any planner of
    # plan/registry.PLANNERS that needs no policy, e.g. "frontier" (Nearest Frontier on the observed map) or
    # "predfrontier" (the predictive expert: goals on the fused map, docs/design.md §5).
    exploration_planner: str = "frontier"
    frontier_retries: int = 1  # times the planner's dropped targets get another chance before "explored"
    # Without a plan of the building (no coverage to measure), exploration ends when the maps' unverified area
    # (predict/verification.py: unknown reachable + expected wrong predicted area) falls below this, m² (issue #56).
    stop_threshold_m2: float = DEFAULT_STOP_THRESHOLD_M2
    progress_every_s: float = 5.0
    band: HeightBand = field(default_factory=HeightBand)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    map_growth: GrowthConfig = field(default_factory=GrowthConfig)  # the maps grow from take-off (mapping/growing.py)
    thresholds: ThresholdConfig = field(default_factory=ThresholdConfig)
    # Mean-safe motions (noise_sigmas 0): the 3-sigma preference of the benchmark's follower models the training
    # simulator's per-action motion noise, while this vehicle tracks minimum-jerk setpoints (0 collisions in 16
    # acceptance flights without it); with it, narrow doorways made the vehicle hover, back off and retry for tens of
    # metres (docs/runtime/README.md).
    follow: FollowConfig = field(default_factory=lambda: FollowConfig(noise_sigmas=0.0))

    def __post_init__(self) -> None:
        entry = PLANNERS.get(self.exploration_planner)
        if entry is None or entry.needs_policy:
            choices = ", ".join(name for name, e in PLANNERS.items() if not e.needs_policy)
            raise ValueError(f"exploration_planner must be one of {choices}, got {self.exploration_planner!r}")
        if not 0 < self.coverage_goal <= 1:
            raise ValueError(f"coverage_goal must be in (0, 1], got {self.coverage_goal}")
        if self.autopilot not in AUTOPILOT_MODES:
            raise ValueError(f"autopilot must be one of {sorted(AUTOPILOT_MODES)}, got {self.autopilot!r}")
        if not (self.home_detour_factor >= 1 and self.home_path_slack >= 1 and self.home_path_every_s > 0):
            raise ValueError(
                "home_detour_factor and home_path_slack must be ≥ 1 and home_path_every_s > 0, got "
                f"{self.home_detour_factor}, {self.home_path_slack}, {self.home_path_every_s}"
            )
        if not self.stop_threshold_m2 >= 0:
            raise ValueError(f"stop_threshold_m2 must be ≥ 0, got {self.stop_threshold_m2}")
        if self.frontier_retries < 0:
            raise ValueError(f"frontier_retries must be ≥ 0, got {self.frontier_retries}")
        if self.setpoint_rate_hz < 10:
            raise ValueError(f"setpoint_rate_hz must be ≥ 10 (docs/design.md §8), got {self.setpoint_rate_hz}")
        positive = (
            "time_limit_s",
            "takeoff_speed_mps",
            "odometry_max_age_s",
            "pose_jump_m",
            "depth_timeout_s",
            "max_hold_s",
            "reanchor_distance_m",
            "progress_every_s",
            "flight_height_m",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


def band_z_range_m(band: HeightBand) -> tuple[float, float]:
    """The height the voxel maps cover: the projected band and one 0.20 m layer either side, on the 0.20 m layer
    boundaries of the band (so both resolutions project exactly the band's layers).

    Nothing outside the band is projected, and rays are clipped to the maps' box, so floor and ceiling returns still
    carve the free space they cross inside it; a box 1.4 m tall instead of floor-to-ceiling cuts the voxel memory
    (0.05 m: 2 bytes of log-odds and 2 of update stamp per voxel) and the ray traversal by more than half.
    """
    layers = math.ceil((band.max_z_m - band.min_z_m) / LOW_RES_M - 1e-9)
    return band.min_z_m - LOW_RES_M, band.min_z_m + (layers + 1) * LOW_RES_M
