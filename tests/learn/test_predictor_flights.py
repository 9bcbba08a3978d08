"""Flights for the predictor's training data: the explorers on the two-room plan."""

import numpy as np

from edge_explorer.learn.predictor_flights import FlightLimits, PlannerExplorer, RandomGoalWalk, fly


def test_random_goal_walk_covers_the_two_rooms_inside_the_configuration_space(scene):
    steps = list(fly(scene, RandomGoalWalk(), np.random.default_rng(0), limits=FlightLimits(max_steps=300)))
    coverage = np.array([s.coverage for s in steps])
    assert np.all(np.diff(coverage) >= 0) and coverage[0] > 0
    assert coverage[-1] > 0.9  # it leaves the first room through the door
    rows, cols = scene.grid.cell_of(*np.array([s.pose[:2] for s in steps]).T)
    assert not scene.blocked[rows, cols].any()


def test_flights_are_reproducible(scene):
    def poses(seed):
        return [s.pose for s in fly(scene, RandomGoalWalk(), np.random.default_rng(seed), limits=FlightLimits(40))]

    assert poses(3) == poses(3) and poses(3) != poses(4)


def test_a_planner_flies_as_an_explorer(scene):
    steps = list(fly(scene, PlannerExplorer("frontier"), np.random.default_rng(0), limits=FlightLimits(max_steps=8)))
    assert len(steps) == 8 and steps[-1].coverage >= steps[0].coverage
