"""Threshold calibration on hand-made samples (edge_explorer.predict.calibration)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_explorer.predict.calibration import CalibrationSample, calibrate, reliability_curve, score_pair
from edge_explorer.predict.thresholding import MAX_PLAN_AREA_M2, ThresholdConfig
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

FULL_AREA = MAX_PLAN_AREA_M2  # t_f = t_f_max: the dynamic factor is 1


def sample(cells: list[tuple[float, int]], observed: int = 0, level: float = 0.5) -> CalibrationSample:
    """One row of unobserved interior cells (probability, truth code), then ``observed`` observed FREE cells."""
    n = len(cells) + observed
    probabilities = np.full(n, 0.5, np.float32)
    truth = np.full(n, FREE, CELL_DTYPE)
    probabilities[: len(cells)] = [p for p, _ in cells]
    truth[: len(cells)] = [t for _, t in cells]
    codes = np.full(n, UNKNOWN, CELL_DTYPE)
    codes[len(cells) :] = FREE
    return CalibrationSample(level, probabilities[None], codes[None], FULL_AREA, truth[None], np.ones((1, n), bool))


# 20 unobserved cells: confident walls, confident free space, and a band of cells the predictor gets half wrong.
FIXTURE = sample(
    [(0.99, OCCUPIED)] * 8  # right at any t_o < 0.99
    + [(0.90, OCCUPIED)] * 1
    + [(0.85, FREE)] * 1  # a wrong wall claim for t_o < 0.85
    + [(0.01, FREE)] * 8  # right at any t_f_max > 0.01
    + [(0.08, FREE)] * 1
    + [(0.11, OCCUPIED)] * 1,  # a wrong free claim for t_f_max > 0.11
    observed=20,
)


def test_score_pair_counts_the_claimed_cells_against_the_truth():
    row = score_pair([FIXTURE], ThresholdConfig(t_f_max=0.12, t_o=0.8))
    assert row.coverage_added == {0.5: pytest.approx(20 / 40)}
    assert row.precision == {0.5: pytest.approx(18 / 20)}
    tight = score_pair([FIXTURE], ThresholdConfig(t_f_max=0.05, t_o=0.95))
    assert tight.precision == {0.5: 1.0} and tight.coverage_added == {0.5: pytest.approx(16 / 40)}


def test_calibration_picks_the_pair_that_adds_most_while_meeting_the_precision():
    result = calibrate([FIXTURE], 0.95, t_f_max_candidates=(0.05, 0.10, 0.12), t_o_candidates=(0.8, 0.88, 0.95))
    # (0.10, 0.88) claims 18 cells, all right; a wider threshold on either side adds a wrong cell (18/19 < 0.95).
    assert result.met_target
    assert result.thresholds == ThresholdConfig(t_f_max=0.10, t_o=0.88)
    assert result.chosen.precision == {0.5: 1.0}
    assert result.chosen.coverage_added == {0.5: pytest.approx(18 / 40)}
    assert len(result.table) == 9 and result.samples_per_level == {0.5: 1}
    assert result.score_of(ThresholdConfig(t_f_max=0.12, t_o=0.8)).precision == {0.5: pytest.approx(0.9)}


def test_the_default_grid_calibrates_a_model_whose_claims_above_099_are_still_wrong():
    # a confident model: its wrong wall claims sit at 0.992, above the old grid's top t_o = 0.99
    confident = sample([(0.999, OCCUPIED)] * 20 + [(0.992, FREE)] * 4 + [(0.001, FREE)] * 20, observed=20)
    result = calibrate([confident], 0.95)
    assert result.met_target and result.thresholds.t_o > 0.992
    assert result.chosen.precision == {0.5: 1.0} and result.chosen.coverage_added == {0.5: pytest.approx(40 / 64)}


def test_a_lower_target_accepts_the_wider_pair():
    result = calibrate([FIXTURE], 0.9, t_f_max_candidates=(0.05, 0.10, 0.12), t_o_candidates=(0.8, 0.88, 0.95))
    assert result.thresholds == ThresholdConfig(t_f_max=0.12, t_o=0.8)


def test_the_target_holds_at_every_level():
    late = sample([(0.99, OCCUPIED), (0.90, FREE), (0.01, FREE)], level=0.8)  # t_o 0.88 is wrong here
    result = calibrate([FIXTURE, late], 0.95, t_f_max_candidates=(0.10,), t_o_candidates=(0.88, 0.95))
    assert result.levels == (0.5, 0.8)
    assert result.thresholds == ThresholdConfig(t_f_max=0.10, t_o=0.95)


def test_without_a_pair_meeting_the_target_the_most_precise_one_is_chosen_and_said():
    noisy = sample([(0.99, OCCUPIED), (0.99, FREE), (0.01, FREE), (0.01, FREE), (0.01, OCCUPIED)])
    result = calibrate([noisy], 0.95, t_f_max_candidates=(0.005, 0.05), t_o_candidates=(0.9,))
    # (0.005, 0.9): the two walls, half right; (0.05, 0.9): all five claims, three right (0.6): the more precise.
    assert not result.met_target
    assert result.thresholds == ThresholdConfig(t_f_max=0.05, t_o=0.9)
    assert result.chosen.worst_precision == pytest.approx(0.6)
    assert result.card_entry()["calibration"]["met_target"] is False


def test_the_reliability_curve_bins_the_unobserved_interior_cells():
    cells = [(0.05, FREE), (0.05, FREE), (0.15, OCCUPIED), (0.95, OCCUPIED), (0.95, FREE), (1.0, OCCUPIED)]
    s = sample([*cells, (float("nan"), OCCUPIED)], observed=2)  # no prediction, and observed cells: left out
    curve = reliability_curve([s], bins=4)
    assert curve.bin_edges == (0.0, 0.25, 0.5, 0.75, 1.0)
    assert curve.cells == (3, 0, 0, 3)
    assert curve.mean_predicted[0] == pytest.approx(0.25 / 3) and curve.mean_predicted[1] is None
    assert curve.occupied_frequency == (pytest.approx(1 / 3), None, None, pytest.approx(2 / 3))


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="at least one sample"):
        calibrate([])
    with pytest.raises(ValueError, match="N_M = 0"):
        calibrate([CalibrationSample(0.5, *(np.zeros((1, 2)),) * 2, 1.0, np.zeros((1, 2)), np.zeros((1, 2), bool))])


def test_the_card_keeps_the_trade_off_front():
    result = calibrate([FIXTURE], 0.95, t_f_max_candidates=(0.05, 0.10, 0.12), t_o_candidates=(0.8, 0.88, 0.95))
    front = {(row.t_f_max, row.t_o) for row in result.front()}
    assert front == {(0.10, 0.88), (0.10, 0.8), (0.12, 0.88), (0.12, 0.8)}  # (1, 18/40), (18/19, 19/40), (0.9, 20/40)
    entry = result.card_entry()
    assert (entry["t_f_max"], entry["t_o"], entry["precision_target"]) == (0.10, 0.88, 0.95)
    assert len(entry["calibration"]["table"]) == 4 and len(result.to_json()["table"]) == 9
