"""Reliability diagram, ECE, MCE and Brier score of predicted probabilities (learn.reliability)."""

import numpy as np
import pytest

from edge_explorer.learn.reliability import GRID_STEPS, ProbabilityCounts, ece, plot_reliability, reliability


def test_a_calibrated_sampler_has_an_ece_near_zero():
    rng = np.random.default_rng(0)
    p = rng.random(400_000)
    y = rng.random(p.size) < p  # occupied with exactly the predicted probability
    rel = reliability(p, y, bins=10)
    assert rel.ece < 0.005 and rel.mce < 0.01
    assert rel.brier == pytest.approx(1 / 6, abs=0.002)  # E[p(1 − p)] for p ~ U(0, 1)
    assert sum(rel.cells) == rel.n == p.size


def test_a_constant_over_confident_predictor_has_the_known_errors():
    p = np.full(1000, 0.9)
    y = np.arange(1000) < 600  # 60 % occupied where the model says 90 %
    rel = reliability(p, y, bins=20)
    assert rel.ece == pytest.approx(0.3) and rel.mce == pytest.approx(0.3)
    assert rel.brier == pytest.approx(0.6 * 0.1**2 + 0.4 * 0.9**2)
    full = [b for b, n in enumerate(rel.cells) if n]
    assert full == [18] and rel.mean_predicted[18] == pytest.approx(0.9)
    assert rel.observed_frequency[18] == pytest.approx(0.6) and rel.mean_predicted[0] is None
    assert ece(p, y, bins=20) == pytest.approx(0.3)


def test_bins_are_weighted_by_their_cell_count():
    # 900 calibrated cells at 0.1 (10 % occupied), 100 cells at 0.9 that are all free
    p = np.r_[np.full(900, 0.1), np.full(100, 0.9)]
    y = np.r_[np.arange(900) < 90, np.zeros(100, bool)]
    rel = reliability(p, y, bins=10)
    assert rel.ece == pytest.approx(0.1 * 0.9) and rel.mce == pytest.approx(0.9)


def test_weights_count_like_repeated_samples_and_nan_is_left_out():
    p, y, w = np.array([0.2, 0.7, 1.0, np.nan]), np.array([0, 1, 1, 1]), np.array([3, 2, 5, 7])
    weighted = reliability(p, y, bins=5, weights=w)
    repeated = reliability(np.repeat(p[:3], w[:3]), np.repeat(y[:3], w[:3]), bins=5)
    assert weighted == repeated and weighted.n == 10
    assert weighted.cells[-1] == 5  # 1.0 falls in the last bin


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="differ"):
        reliability(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        reliability(np.array([1.5]), np.array([1]))
    with pytest.raises(ValueError, match="no sample"):
        reliability(np.array([np.nan]), np.array([1]))
    with pytest.raises(ValueError, match="bin"):
        reliability(np.array([0.5]), np.array([1]), bins=0)


def test_counts_give_the_figures_of_the_cells_they_count(tmp_path):
    rng = np.random.default_rng(1)
    p = rng.integers(0, 257, 50_000) / 256  # the int8 model's levels: exact on the counting grid
    p[:10] = np.nan
    y = rng.random(p.size) < 0.3
    counts = ProbabilityCounts()
    counts.add(p[:20_000], y[:20_000])
    rest = ProbabilityCounts()
    rest.add(p[20_000:], y[20_000:])
    merged = counts.merge(rest)
    assert merged.total == p.size - 10
    direct = reliability(p, y, bins=20)
    assert merged.reliability(20).ece == pytest.approx(direct.ece, abs=1e-12)
    assert merged.reliability(20).brier == pytest.approx(direct.brier, abs=1e-12)
    again = ProbabilityCounts.from_json(merged.to_json())
    assert np.array_equal(again.free, merged.free) and np.array_equal(again.occupied, merged.occupied)
    squared = merged.reliability(20, transform=lambda q: q**2)  # a calibration map goes through the counts
    assert squared.ece == pytest.approx(reliability(p**2, y, bins=20).ece, abs=1e-6)
    assert GRID_STEPS % 256 == 0
    plot_reliability({"raw": direct, "squared": squared}, tmp_path / "rel.png", "test")
    assert (tmp_path / "rel.png").read_bytes()[:4] == b"\x89PNG"
