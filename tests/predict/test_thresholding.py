"""Dynamic thresholding (edge_explorer.predict.thresholding)."""

import math

import numpy as np
import pytest

from edge_explorer.predict.thresholding import (
    MAX_PLAN_AREA_M2,
    ThresholdConfig,
    beyond_envelope,
    free_threshold,
    observed_extent_m,
    threshold_probabilities,
    thresholded_map,
)
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN


def test_free_threshold_grows_with_the_observed_area():
    config = ThresholdConfig()
    assert MAX_PLAN_AREA_M2 == 231.0
    assert free_threshold(0.0, config) == 0.0
    saturation = 231.0 * 0.1**0.25  # 10·r⁴ = 1
    assert free_threshold(saturation, config) == pytest.approx(0.04)
    assert free_threshold(2 * saturation, config) == pytest.approx(0.04)
    assert free_threshold(saturation / 2, config) == pytest.approx(0.04 / 16)
    assert free_threshold(50.0, ThresholdConfig(max_plan_area_m2=100.0)) == pytest.approx(0.04 * min(1, 10 * 0.5**4))


def test_f_t():
    p = np.array([0.0, 0.01, 0.04, 0.5, 0.94, 0.95, 1.0, np.nan])
    np.testing.assert_array_equal(
        threshold_probabilities(p, 0.04, 0.94), [FREE, FREE, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED, UNKNOWN]
    )


def test_observed_cells_override_the_prediction():
    observed = np.array([[FREE, UNKNOWN], [OCCUPIED, UNKNOWN]], dtype=CELL_DTYPE)
    p = np.array([[1.0, 1.0], [0.0, 0.0]])
    big_area = 1000.0  # t_f at its maximum
    np.testing.assert_array_equal(thresholded_map(p, observed, big_area), [[FREE, OCCUPIED], [OCCUPIED, FREE]])
    # with nothing observed yet t_f = 0: nothing is predicted free
    np.testing.assert_array_equal(thresholded_map(p, observed, 0.0), [[FREE, OCCUPIED], [OCCUPIED, UNKNOWN]])
    with pytest.raises(ValueError, match="differ"):
        thresholded_map(np.zeros(3), observed, 0.0)


def _corridor(length_cells: int, width_cells: int) -> np.ndarray:
    """A 0.20 m map: an observed free corridor of the given size along the top rows, UNKNOWN elsewhere."""
    codes = np.full((80, 160), UNKNOWN, dtype=CELL_DTYPE)
    codes[:width_cells, :length_cells] = FREE
    return codes


def test_observed_extent_is_the_bounding_box_of_the_observed_cells():
    assert observed_extent_m(np.full((5, 5), UNKNOWN, dtype=CELL_DTYPE)) == (0.0, 0.0)
    assert observed_extent_m(_corridor(100, 10)) == pytest.approx((20.0, 2.0))
    assert observed_extent_m(_corridor(10, 40)) == pytest.approx((8.0, 2.0))  # long, short whatever the axis
    assert observed_extent_m(_corridor(100, 10), resolution_m=0.05) == pytest.approx((5.0, 0.5))


def test_no_cell_is_predicted_occupied_beyond_the_training_envelope():
    p = np.full((80, 160), 0.99)  # the predictor paints everything unseen solid
    inside = _corridor(110, 60)  # 22 × 12 m: within 21 × 11 m + 2 m
    assert not beyond_envelope(inside, ThresholdConfig())
    assert (thresholded_map(p, inside, 1000.0)[inside == UNKNOWN] == OCCUPIED).all()
    for beyond in (_corridor(120, 10), _corridor(75, 70)):  # 24 m long; 15 × 14 m: 14 m on the short side
        assert beyond_envelope(beyond, ThresholdConfig())
        fused = thresholded_map(p, beyond, 1000.0)
        assert (fused[beyond == UNKNOWN] == UNKNOWN).all()
        np.testing.assert_array_equal(fused[beyond != UNKNOWN], FREE)  # observed cells keep their state
    # predicted FREE cells stay: only the walls the predictor invents are dropped
    low = np.full((80, 160), 0.0)
    assert (thresholded_map(low, _corridor(120, 10), 1000.0)[_corridor(120, 10) == UNKNOWN] == FREE).all()
    # a predictor trained on larger buildings widens its envelope
    assert not beyond_envelope(_corridor(120, 10), ThresholdConfig(envelope_m=(30.0, 20.0)))


def test_a_whole_floor_model_s_thresholds_apply_beyond_the_envelope_and_keep_its_walls():
    floors = ThresholdConfig(t_f_max=0.2, t_o=0.8, envelope_m=(math.inf, math.inf))
    config = ThresholdConfig(beyond=floors)
    p = np.full((80, 160), 0.9)  # above the whole-floor model's t_o, below the default's 0.94
    p[:, :40] = 0.1  # below its t_f_max, above the default's 0.04
    inside, beyond = _corridor(110, 60), _corridor(120, 10)
    # within the envelope the config's own thresholds: nothing is sure enough
    assert (thresholded_map(p, inside, 1000.0, config)[inside == UNKNOWN] == UNKNOWN).all()
    fused = thresholded_map(p, beyond, 1000.0, config)
    unseen = beyond == UNKNOWN
    assert (fused[unseen & (p > 0.5)] == OCCUPIED).all() and (fused[unseen & (p < 0.5)] == FREE).all()
    np.testing.assert_array_equal(fused[~unseen], FREE)  # observed cells keep their state


def test_config_is_validated():
    with pytest.raises(ValueError):
        ThresholdConfig(t_f_max=0.5, t_o=0.4)
    with pytest.raises(ValueError):
        ThresholdConfig(max_plan_area_m2=0.0)
    with pytest.raises(ValueError):
        ThresholdConfig(envelope_m=(10.0, 20.0))
