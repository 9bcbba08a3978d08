"""Predictor input encoding, output decoding and training targets (edge_explorer.predict.encoding)."""

import numpy as np
import pytest

from edge_explorer.predict.encoding import (
    INPUT_CHANNELS,
    decode_probabilities,
    encode_windows,
    loss_weights,
    occupancy_target,
)
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN


def test_two_binary_channels_free_then_occupied():
    window = np.array([[FREE, UNKNOWN], [OCCUPIED, FREE]], dtype=CELL_DTYPE)
    x = encode_windows(window)
    assert x.shape == (INPUT_CHANNELS, 2, 2) and x.dtype == np.float32
    np.testing.assert_array_equal(x[0], [[1, 0], [0, 1]])
    np.testing.assert_array_equal(x[1], [[0, 0], [1, 0]])
    batch = encode_windows(np.stack([window, -window]))
    assert batch.shape == (2, INPUT_CHANNELS, 2, 2)
    np.testing.assert_array_equal(batch[1, 0], [[0, 0], [1, 0]])  # the negated window swaps free and occupied
    with pytest.raises(ValueError):
        encode_windows(np.zeros(4, dtype=CELL_DTYPE))


def test_decode_accepts_the_usual_output_layouts():
    p = np.linspace(0, 1, 6, dtype=np.float32).reshape(2, 3)
    for raw in (p, p[None], p[None, None]):
        np.testing.assert_array_equal(decode_probabilities(raw), p)
    with pytest.raises(ValueError):
        decode_probabilities(np.zeros((2, 2, 3)))


def test_targets_call_the_exterior_occupied_and_weights_mask_observed_cells():
    truth = np.array([[FREE, OCCUPIED, UNKNOWN]], dtype=CELL_DTYPE)
    np.testing.assert_array_equal(occupancy_target(truth), [[0, 1, 1]])
    observed = np.array([[UNKNOWN, UNKNOWN, UNKNOWN]], dtype=CELL_DTYPE)
    np.testing.assert_allclose(loss_weights(truth, observed, 0.1, 0.0), [[1, 1, 0.1]])
    observed[0, 0] = FREE
    np.testing.assert_allclose(loss_weights(truth, observed, 0.1, 0.3), [[0.3, 1, 0.1]])


def test_wall_weight_scales_only_unobserved_interior_walls():
    truth = np.array([[FREE, OCCUPIED, UNKNOWN, OCCUPIED]], dtype=CELL_DTYPE)
    observed = np.array([[UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED]], dtype=CELL_DTYPE)
    np.testing.assert_allclose(loss_weights(truth, observed, 0.1, 0.0, wall_weight=3.0), [[1, 3, 0.1, 0]])
