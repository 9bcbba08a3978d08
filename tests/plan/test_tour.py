"""The exact open tour of the global layer (plan/tour.py) against every permutation on small instances."""

import itertools

import numpy as np
import pytest

from edge_explorer.plan.tour import MAX_TOUR_STOPS, open_tour


def _length(cost: np.ndarray, order: list[int] | tuple[int, ...]) -> float:
    return float(sum(cost[a, b] for a, b in zip(order, order[1:])))


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_the_tour_starts_at_the_vehicle_visits_every_stop_once_and_is_the_shortest(n):
    rng = np.random.default_rng(n)
    for _ in range(10):
        xy = rng.uniform(0.0, 50.0, (n, 2))
        cost = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        order = open_tour(cost)
        assert order[0] == 0 and sorted(order) == list(range(n))
        best = min(_length(cost, (0, *rest)) for rest in itertools.permutations(range(1, n)))
        assert _length(cost, order) == pytest.approx(best)


def test_a_leg_with_no_way_is_taken_only_when_nothing_else_remains():
    cost = np.array([[0.0, 1.0, 5.0, 9.0], [1.0, 0.0, np.inf, 4.0], [5.0, np.inf, 0.0, 4.0], [9.0, 4.0, 4.0, 0.0]])
    assert open_tour(cost) == [0, 1, 3, 2]


def test_more_stops_than_the_exact_programme_takes_is_a_clear_error():
    with pytest.raises(ValueError, match="at most"):
        open_tour(np.zeros((MAX_TOUR_STOPS + 2,) * 2))
