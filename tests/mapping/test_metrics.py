"""docs/design.md §7 metrics (edge_explorer.mapping.metrics)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_explorer.mapping.metrics import MapMetrics, known_codes, map_metrics, path_length_m
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

OC, F, U = OCCUPIED, FREE, UNKNOWN


def _codes(rows):
    return np.array(rows, dtype=CELL_DTYPE)


TRUTH = _codes([[OC, OC, OC], [OC, F, F], [OC, F, F]])
INTERIOR = np.ones((3, 3), dtype=bool)


def test_observed_only_by_hand():
    observed = _codes([[OC, U, U], [OC, F, U], [U, U, OC]])
    m = map_metrics(observed, TRUTH, INTERIOR)
    # correct: (0,0) OC, (1,0) OC, (1,1) F; (2,2) is observed OC but truly F
    assert (m.n_m, m.t, m.tp, m.known) == (9, 3, 2, 4)
    assert m.f1 == pytest.approx(2 / (2 + 0.5 * 6))
    assert m.coverage == pytest.approx(4 / 9)
    assert m.correct_coverage == pytest.approx(3 / 9)


def test_prediction_fills_unobserved_cells_only():
    observed = _codes([[OC, U, U], [OC, F, U], [U, U, OC]])
    thresholded = _codes([[F, OC, U], [OC, OC, F], [OC, U, F]])  # (0,0) and (1,1) and (2,2) are overridden
    m = map_metrics(observed, TRUTH, INTERIOR, thresholded)
    # known: (0,0) OC✓ (0,1) OC✓ (1,0) OC✓ (1,1) F✓ (1,2) F✓ (2,0) OC✓ (2,2) OC✗; (0,2), (2,1) unknown
    assert (m.t, m.tp, m.known) == (6, 4, 7)
    assert m.f1 == pytest.approx(4 / (4 + 0.5 * 3))
    assert m.coverage == pytest.approx(7 / 9) and m.correct_coverage == pytest.approx(6 / 9)
    np.testing.assert_array_equal(known_codes(observed, thresholded)[2], [OC, U, OC])


def test_exterior_cells_do_not_count():
    interior = np.zeros((3, 3), dtype=bool)
    interior[1:, 1:] = True
    observed = _codes([[F, F, F], [F, F, U], [U, U, U]])
    m = map_metrics(observed, TRUTH, interior)
    assert (m.n_m, m.t, m.tp, m.known) == (4, 1, 0, 1)
    assert m.f1 == 0.0


def _reference(observed, truth, interior, thresholded):
    known = observed if thresholded is None else np.where(observed != U, observed, thresholded)
    n_m = interior.sum()
    t = ((known == truth) & interior).sum()
    tp = ((known == truth) & interior & (truth == OC)).sum()
    covered = ((known != U) & interior).sum()
    return n_m, t, tp, covered


@settings(deadline=None)  # the first example may compile numba kernels
@given(
    seed=st.integers(0, 2**32 - 1), shape=st.tuples(st.integers(1, 6), st.integers(1, 6)), with_prediction=st.booleans()
)
def test_counts_match_the_definitions(seed, shape, with_prediction):
    rng = np.random.default_rng(seed)
    truth = rng.choice([OC, F], size=shape).astype(CELL_DTYPE)
    interior = rng.random(shape) < 0.8
    interior.flat[0] = True
    observed = rng.integers(-1, 2, size=shape).astype(CELL_DTYPE)
    thresholded = rng.integers(-1, 2, size=shape).astype(CELL_DTYPE) if with_prediction else None
    m = map_metrics(observed, truth, interior, thresholded)
    n_m, t, tp, covered = _reference(observed, truth, interior, thresholded)
    assert (m.n_m, m.t, m.tp, m.known) == (n_m, t, tp, covered)
    denominator = tp + 0.5 * (n_m - t)
    assert m.f1 == pytest.approx(tp / denominator if denominator else 1.0)


@settings(deadline=None)  # the first example may compile numba kernels
@given(seed=st.integers(0, 2**32 - 1), shape=st.tuples(st.integers(1, 8), st.integers(1, 8)))
def test_perfect_map_scores_one(seed, shape):
    rng = np.random.default_rng(seed)
    truth = rng.choice([OC, F], size=shape).astype(CELL_DTYPE)
    interior = np.ones(shape, dtype=bool)
    for m in (
        map_metrics(truth.copy(), truth, interior),
        map_metrics(np.zeros(shape, CELL_DTYPE), truth, interior, truth.copy()),
    ):
        assert m.f1 == 1.0 and m.coverage == 1.0 and m.correct_coverage == 1.0


def test_f1_of_a_perfect_map_without_occupied_cells_is_one():
    assert MapMetrics(n_m=4, t=4, tp=0, known=4).f1 == 1.0


def test_bad_inputs():
    with pytest.raises(ValueError, match="shapes differ"):
        map_metrics(TRUTH, TRUTH, np.ones((2, 2), dtype=bool))
    with pytest.raises(ValueError, match="N_M = 0"):
        map_metrics(TRUTH, TRUTH, np.zeros((3, 3), dtype=bool))
    with pytest.raises(ValueError, match="differ"):
        map_metrics(TRUTH, TRUTH, INTERIOR, np.zeros((2, 2), dtype=CELL_DTYPE))


def test_path_length():
    assert path_length_m(np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [3.0, 5.0]])) == pytest.approx(6.0)
    assert path_length_m(np.zeros((1, 2))) == 0.0
    with pytest.raises(ValueError):
        path_length_m(np.zeros(3))
