"""The predictor's probability calibration map and its thresholds (predict.probability_calibration, thresholding)."""

import dataclasses

import numpy as np
import pytest

from edge_explorer.predict.probability_calibration import ProbabilityCalibration, fit, order_violations
from edge_explorer.predict.thresholding import ThresholdConfig, free_threshold, occupied_threshold, thresholded_map
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

SHRINK = ProbabilityCalibration("beta", a=0.6, b=-1.2, c=0.87)  # about the shipped model's fit: over-confidence
LEVELS = np.arange(257) / 256  # the int8 model's outputs


def test_the_map_is_strictly_increasing_from_0_to_1_and_keeps_nan():
    p = np.r_[LEVELS, np.nan].astype(np.float32)
    out = SHRINK(p)
    assert out.dtype == np.float32 and np.isnan(out[-1])
    assert out[0] == 0.0 and out[-2] == 1.0
    assert np.all(np.diff(out[:-1]) > 0)
    platt = ProbabilityCalibration("platt", a=1.0, b=0.0, c=1.0)  # identity
    assert np.allclose(platt(LEVELS), LEVELS, atol=1e-7)


def test_the_map_reads_back_from_json_and_bad_maps_are_refused():
    for cal in (SHRINK, ProbabilityCalibration("platt", a=0.5, b=0.1, c=0.5)):
        assert ProbabilityCalibration.from_json(cal.to_json()) == cal
    with pytest.raises(ValueError, match="a, c > 0"):
        ProbabilityCalibration("beta", a=-1.0, b=0.0, c=1.0)
    with pytest.raises(ValueError, match="a = c"):
        ProbabilityCalibration("platt", a=1.0, b=0.0, c=2.0)
    with pytest.raises(ValueError, match="unknown"):
        ProbabilityCalibration("isotonic", a=1.0, b=0.0, c=1.0)


@pytest.mark.parametrize("method", ["beta", "platt"])
def test_the_fit_recovers_a_known_map(method):
    truth_map = ProbabilityCalibration(method, a=0.6, b=-0.8, c=0.6 if method == "platt" else 0.9)
    rng = np.random.default_rng(0)
    p = rng.integers(1, 256, 300_000) / 256
    y = rng.random(p.size) < truth_map(p)
    fitted = fit(p, y, method=method)
    assert fitted.method == method
    assert np.max(np.abs(fitted(LEVELS) - truth_map(LEVELS))) < 0.01


def test_mapped_thresholds_cut_the_calibrated_probabilities_where_the_raw_ones_were_cut():
    raw = ThresholdConfig(t_f_max=0.35, t_o=0.96)
    cal = dataclasses.replace(raw, calibration=SHRINK)
    assert occupied_threshold(raw) == 0.96 and occupied_threshold(cal) == pytest.approx(float(SHRINK(0.96)))
    area = 80.0  # the dynamic factor is below 1 here: f(t_f_max · factor), not f(t_f_max) · factor
    assert free_threshold(area, cal) == pytest.approx(float(SHRINK(free_threshold(area, raw))))
    rng = np.random.default_rng(3)
    for area in (0.0, 0.04, 20.0, 80.0, 110.0, 129.8, 200.0):
        probs = (rng.integers(0, 257, (64, 64)) / 256).astype(np.float32)
        probs[:3] = np.nan
        observed = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], dtype=CELL_DTYPE), (64, 64), p=[0.7, 0.2, 0.1])
        for grid in (probs, probs.astype(np.float64)):  # float32 in the daemon, float64 after unshift's NaN fill
            before = thresholded_map(grid, observed, area, raw)
            after = thresholded_map(SHRINK(grid), observed, area, cal)
            assert np.array_equal(before, after)
    assert not order_violations(SHRINK, LEVELS, [free_threshold(n * 0.04, raw) for n in range(3300)] + [0.96])


def test_a_map_that_merges_levels_across_a_threshold_is_caught():
    saturating = ProbabilityCalibration("beta", a=1.0, b=40.0, c=1.0)  # every level above ~1e-9 rounds to 1.0
    assert (0.25, 0.5) in order_violations(saturating, np.array([0.25, 0.75]), [0.5])
    assert not order_violations(SHRINK, np.array([0.25, 0.75]), [0.5])
