"""Dynamic thresholding (edge_explorer.predict.thresholding)."""

import numpy as np
import pytest

from edge_explorer.predict.thresholding import (
    MAX_PLAN_AREA_M2,
    ThresholdConfig,
    free_threshold,
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


def test_config_is_validated():
    with pytest.raises(ValueError):
        ThresholdConfig(t_f_max=0.5, t_o=0.4)
    with pytest.raises(ValueError):
        ThresholdConfig(max_plan_area_m2=0.0)
