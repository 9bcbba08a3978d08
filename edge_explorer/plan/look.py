"""Look before leaving: turn in place towards unknown space already in sight before flying to a new goal.

The camera sees an 87° cone (DESIGN.md §6), and the vehicle faces where it flies. So when the predictive expert (or
the learned planner, which flies its loop) starts a new goal, unknown space beside or behind the vehicle may lie in
plain sight, within range and behind no wall, yet outside the cone it is about to fly along; to see it later the
vehicle must come back. A turn in place shows it for almost no path: a hovering turn moves the vehicle only by its
motion noise, ~1 cm a step. The exploration's cost is path length (the paper's metric); turns cost time, about one
control step each (at most :attr:`LookConfig.max_steps` per goal), and the benchmark reports steps beside paths.

:func:`look_heading` scores a few headings by the unknown cells their cone would show from the vehicle (cells whose
line of sight crosses no occupied cell, :func:`~edge_explorer.plan.predictive.visible_unknown`) and keeps the best
one if it shows at least ``min_gain_cells`` more than the cone along the way out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LookConfig:
    """When a new goal starts with a turn in place (see the module docstring)."""

    enabled: bool = True
    min_gain_cells: int = 30  # the turn must show this many more unknown 0.20 m cells (1.2 m²) than flying on would
    max_steps: int = 6  # turn steps at most (6 × 30° = half a turn), then fly the goal whatever the heading
    headings: int = 12  # candidate headings, evenly spaced

    def __post_init__(self) -> None:
        if self.min_gain_cells < 1 or self.max_steps < 1 or self.headings < 1:
            raise ValueError("min_gain_cells, max_steps and headings must be ≥ 1")


def cone_counts(
    points_xy_m: np.ndarray, viewpoint_xy_m: np.ndarray, headings_rad: np.ndarray, fov_rad: float
) -> np.ndarray:
    """How many of ``points_xy_m`` ((K, 2) metres) lie in the ``fov_rad`` cone of each heading from the viewpoint."""
    delta = np.asarray(points_xy_m, dtype=np.float64).reshape(-1, 2) - np.asarray(viewpoint_xy_m, dtype=np.float64)
    bearings = np.arctan2(delta[:, 1], delta[:, 0])
    off = np.angle(np.exp(1j * (bearings[None, :] - np.asarray(headings_rad, dtype=np.float64)[:, None])))
    return (np.abs(off) <= 0.5 * fov_rad).sum(axis=1)


def departure_heading_rad(path_xy_m: np.ndarray, xy_m: np.ndarray, ahead_m: float, final_yaw_rad: float) -> float:
    """Where the vehicle will face when it flies off along ``path_xy_m``: towards the first path point at least
    ``ahead_m`` away, or ``final_yaw_rad`` when the whole path lies closer (the goal is here)."""
    path = np.asarray(path_xy_m, dtype=np.float64).reshape(-1, 2)
    distance = np.hypot(path[:, 0] - xy_m[0], path[:, 1] - xy_m[1])
    far = np.flatnonzero(distance >= ahead_m)
    if len(far) == 0:
        return final_yaw_rad
    dx, dy = path[far[0]] - xy_m
    return math.atan2(dy, dx)


def look_heading(
    visible_xy_m: np.ndarray,
    viewpoint_xy_m: np.ndarray,
    departure_rad: float,
    fov_rad: float,
    config: LookConfig = LookConfig(),
) -> float | None:
    """The heading to turn to before flying off, or ``None`` when no cone shows ``config.min_gain_cells`` more of
    the visible unknown cells ``visible_xy_m`` than the cone along ``departure_rad``."""
    if not config.enabled or len(visible_xy_m) < config.min_gain_cells:
        return None
    headings = departure_rad + np.arange(config.headings) * (2.0 * math.pi / config.headings)
    counts = cone_counts(visible_xy_m, viewpoint_xy_m, headings, fov_rad)
    best = int(np.argmax(counts))
    if counts[best] - counts[0] < config.min_gain_cells:
        return None
    return float(math.atan2(math.sin(headings[best]), math.cos(headings[best])))
