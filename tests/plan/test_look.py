"""Look before leaving: headings scored by the visible unknown cells in their cone, and the turn in place a new goal
of the predictive expert starts with (edge_explorer.plan.look, edge_explorer.plan.predictive)."""

import math

import numpy as np
import pytest

from edge_explorer.mapping.observed import LOW_RES_M, ObservedMaps, coarsen_codes
from edge_explorer.plan.frontier import Goal
from edge_explorer.plan.look import LookConfig, cone_counts, departure_heading_rad, look_heading
from edge_explorer.plan.predictive import PredictiveConfig, PredictiveFrontier
from edge_explorer.sim.dynamics import Action
from edge_explorer.world.grid import UNKNOWN, resolution_factor
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

FOV = math.radians(87.0)
_FLYING = (Action.FORWARD, Action.TURN_LEFT_FORWARD, Action.TURN_RIGHT_FORWARD)  # the motions that translate


def _ring(bearing_rad: float, n: int, here=(0.0, 0.0)) -> np.ndarray:
    """``n`` points 2 m from ``here`` within ±20° of ``bearing_rad``."""
    angles = bearing_rad + np.linspace(-math.radians(20), math.radians(20), n)
    return np.stack([here[0] + 2 * np.cos(angles), here[1] + 2 * np.sin(angles)], axis=1)


def test_a_cone_counts_the_points_within_half_its_field_of_view():
    points = np.concatenate([_ring(0.0, 5), _ring(math.pi / 2, 3), _ring(math.pi, 7)])
    counts = cone_counts(points, np.zeros(2), np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]), FOV)
    assert counts.tolist() == [5, 3, 7, 0]
    assert cone_counts(_ring(math.pi, 4), np.zeros(2), np.array([-math.pi + 0.01]), FOV).tolist() == [4]  # wraps


def test_the_look_turns_to_the_richest_cone_only_if_it_shows_enough_more_than_flying_off():
    config = LookConfig(min_gain_cells=10)
    behind = _ring(math.pi, 40)
    heading = look_heading(behind, np.zeros(2), 0.0, FOV, config)
    assert heading is not None and abs(abs(heading) - math.pi) < 1e-6
    assert look_heading(behind, np.zeros(2), math.pi, FOV, config) is None  # flying that way shows them anyway
    assert look_heading(_ring(math.pi, 9), np.zeros(2), 0.0, FOV, config) is None  # too few to turn for
    ahead_and_behind = np.concatenate([_ring(0.0, 30), _ring(math.pi, 35)])
    assert look_heading(ahead_and_behind, np.zeros(2), 0.0, FOV, config) is None  # only 5 more than ahead
    assert look_heading(behind, np.zeros(2), 0.0, FOV, LookConfig(enabled=False)) is None
    with pytest.raises(ValueError):
        LookConfig(max_steps=0)


def test_the_departure_heading_points_along_the_path_or_is_the_goal_heading_when_the_goal_is_here():
    path = np.array([[0.0, 0.0], [0.3, 0.0], [0.3, 2.0]])
    assert departure_heading_rad(path, np.zeros(2), 0.8, 1.0) == pytest.approx(math.atan2(2.0, 0.3))
    assert departure_heading_rad(path[:2], np.zeros(2), 0.8, 1.0) == 1.0


class _EastwardExpert(PredictiveFrontier):
    """The expert with its goal fixed: the door to the east room (the look, not the choice, is under test)."""

    def select_goal(self, view, pose):
        path = np.array([pose[:2], [1.5, 1.5], [1.8, 1.5]])
        return Goal(path, 0.0, np.flatnonzero(view.frontier)[:1], done_fraction=1.0)


def _west_strip_unknown(raster) -> ObservedMaps:
    """Everything seen but the west of the west room (x < 0.9 m)."""
    codes = raster.truth_codes()
    codes[:, : raster.grid.cell_of(0.9, 0.0)[1]] = UNKNOWN
    factor = resolution_factor(raster.grid.resolution_m, LOW_RES_M)
    return ObservedMaps(raster.grid, raster.grid.coarsened(factor), codes, coarsen_codes(codes, factor))


def test_a_new_goal_starts_with_a_turn_in_place_towards_the_unknown_space_behind():
    rooms = rasterize(two_room_plan(), 0.05)
    maps, pose = _west_strip_unknown(rooms), (1.3, 1.5, 0.0)  # facing the door, the unseen strip behind
    looking = _EastwardExpert(PredictiveConfig(look=LookConfig(min_gain_cells=5)))
    first = looking.act(maps, pose, int(Action.HOVER), None)
    assert first in (Action.TURN_LEFT, Action.TURN_RIGHT)  # no translation: the view behind costs no path
    flying = _EastwardExpert(PredictiveConfig(look=LookConfig(enabled=False)))
    assert flying.act(maps, pose, int(Action.HOVER), None) in _FLYING
    turned, headings = pose, []
    for _ in range(3 * LookConfig().max_steps):  # the turns, applied by hand (the map stays as it is)
        headings.append(turned[2])
        action = looking.act(maps, turned, int(Action.HOVER), None)
        if action not in (Action.TURN_LEFT, Action.TURN_RIGHT):
            break
        turned = (turned[0], turned[1], turned[2] + (math.pi / 6 if action == Action.TURN_LEFT else -math.pi / 6))
    assert min(math.cos(h) for h in headings) < -0.5  # it faced the unseen west …
    assert action in _FLYING  # … then flew the goal
