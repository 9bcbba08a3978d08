"""The unverified area of a flight's maps (edge_explorer.predict.verification): the map stop rule's figure."""

import math

import numpy as np
import pytest

from edge_explorer.predict.verification import unverified_area_m2
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

RES = 0.2
CELL = RES**2


def room(size: int = 20, margin: int = 3) -> np.ndarray:
    """An observed closed room: a wall ring around ``size - 2``² free cells, unknown outside."""
    codes = np.full((size + 2 * margin, size + 2 * margin), UNKNOWN, dtype=CELL_DTYPE)
    codes[margin : margin + size, margin : margin + size] = OCCUPIED
    codes[margin + 1 : margin + size - 1, margin + 1 : margin + size - 1] = FREE
    return codes


def test_a_fully_observed_closed_room_has_nothing_unverified():
    observed = room()
    area = unverified_area_m2(observed, observed, None, RES)
    assert area.total_m2 == 0.0 and area.unknown_reachable_m2 == 0.0 and area.expected_wrong_m2 == 0.0
    assert area.verified_m2 == pytest.approx(20 * 20 * CELL)  # the room and its walls, not the outside


def test_an_unknown_pocket_behind_a_frontier_counts_and_a_sealed_one_does_not():
    observed = room()
    observed[8:11, 8:11] = UNKNOWN  # a 3 × 3 pocket in the open: the vehicle can fly there and look
    area = unverified_area_m2(observed, observed, None, RES)
    assert area.unknown_reachable_m2 == pytest.approx(9 * CELL)
    sealed = room()
    sealed[14:19, 14:19] = OCCUPIED  # a tall cupboard whose inside no sensor sees
    sealed[15:18, 15:18] = UNKNOWN
    assert unverified_area_m2(sealed, sealed, None, RES).total_m2 == 0.0


def test_unknown_space_counts_only_to_the_reach_depth_behind_a_gap():
    observed = np.full((60, 60), UNKNOWN, dtype=CELL_DTYPE)  # a big map, mostly unknown
    observed[20:31, 20:31] = room(11, 0)
    observed[25, 30] = FREE  # a one-cell gap in the east wall: the outside leaks in
    area = unverified_area_m2(observed, observed, None, RES, reach_m=1.0)
    assert 0 < area.unknown_reachable_m2 <= (2 * 5**2 + 2 * 5 + 1) * CELL  # a 4-connected 1 m diamond at most


def test_a_confident_prediction_counts_little_an_unsure_one_half_its_area():
    observed = room()
    observed[4:22, 12:22] = UNKNOWN  # the east part of the room not seen yet …
    fused = room()  # … predicted as it is: free, walled
    predicted = (observed == UNKNOWN) & (fused != UNKNOWN)
    n_free = int((predicted & (fused == FREE)).sum())
    n_wall = int((predicted & (fused == OCCUPIED)).sum())
    probs = np.where(fused == OCCUPIED, 0.98, 0.02).astype(np.float32)
    confident = unverified_area_m2(observed, fused, probs, RES)
    assert confident.unknown_reachable_m2 == 0.0
    assert confident.predicted_m2 == pytest.approx((n_free + n_wall) * CELL)
    assert confident.expected_wrong_m2 == pytest.approx(0.02 * (n_free + n_wall) * CELL, rel=1e-5)
    unsure = unverified_area_m2(observed, fused, np.full(probs.shape, 0.5, np.float32), RES)
    assert unsure.expected_wrong_m2 == pytest.approx(0.5 * unsure.predicted_m2)
    assert unsure.total_m2 > 10 * confident.total_m2


def test_predicted_cells_beyond_observed_walls_do_not_count_and_nothing_seen_is_unverified():
    observed = room()
    fused = observed.copy()
    fused[fused == UNKNOWN] = OCCUPIED  # the predictor paints the outside solid, unsure of it
    probs = np.full(fused.shape, 0.6, np.float32)
    area = unverified_area_m2(observed, fused, probs, RES)
    assert area.predicted_m2 == 0.0 and area.total_m2 == 0.0  # the flight neither needs nor can check them
    blank = np.full((10, 10), UNKNOWN, dtype=CELL_DTYPE)
    assert math.isinf(unverified_area_m2(blank, blank, None, RES).total_m2)
    with pytest.raises(ValueError, match="shape"):
        unverified_area_m2(blank, blank[:5], None, RES)
