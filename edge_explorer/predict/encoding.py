"""The map predictor's input encoding, output meaning and training targets (numpy only, no torch).

Training, evaluation, export calibration and the on-device daemon all call these functions, so the network sees in
flight exactly what it saw in training (docs/design.md §2).

Input
-----
The predictor reads the north-up low-res ego window (:func:`edge_explorer.mapping.ego.pad_shift`, 256×256 int8
codes at 0.20 m, robot cell at (128, 128)) encoded as two binary float32 channels, NCHW::

    channel 0  FREE      1.0 where the cell was observed free, else 0.0
    channel 1  OCCUPIED  1.0 where the cell was observed occupied, else 0.0

UNKNOWN is (0, 0), so the convolutions' zero padding reads as "unknown" — the same as the UNKNOWN fill of
``pad_shift`` beyond the map. Two channels instead of one trinary channel (−1/0/1) keep "free" and "occupied" apart
without an ordering between them, and 0/1 inputs quantize to int8 exactly.

Output
------
One channel, the probability that each cell of the same window is OCCUPIED (after the network's sigmoid), float32
in [0, 1]; :func:`edge_explorer.mapping.ego.unshift` puts it back on the map and
:func:`edge_explorer.predict.thresholding.thresholded_map` turns it into codes.

Targets
-------
:func:`occupancy_target`: 1.0 for occupied cells of the ground truth *and for the exterior* (cells outside the
building, UNKNOWN in the truth), 0.0 for interior free cells. Calling the exterior occupied teaches the network
never to invent free space outside the walls, where the vehicle cannot fly; :func:`loss_weights` gives those
cells a small weight so they do not dominate a 256×256 window that is mostly exterior.
"""

from __future__ import annotations

import numpy as np

from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN

INPUT_CHANNELS = 2  # (free, occupied)
OUTPUT_CHANNELS = 1  # P(occupied)


def encode_windows(windows: np.ndarray) -> np.ndarray:
    """int8 ego windows (H, W) or (N, H, W) → float32 network input (2, H, W) or (N, 2, H, W)."""
    windows = np.asarray(windows)
    if windows.ndim not in (2, 3):
        raise ValueError(f"expected ego windows of shape (H, W) or (N, H, W), got {windows.shape}")
    channel_axis = windows.ndim - 2
    return np.stack([windows == FREE, windows == OCCUPIED], axis=channel_axis).astype(np.float32)


def decode_probabilities(output: np.ndarray) -> np.ndarray:
    """A backend's raw output ((1, 1, H, W), (1, H, W) or (H, W)) → float32 (H, W) occupancy probabilities."""
    out = np.asarray(output, dtype=np.float32)
    if out.ndim < 2 or any(n != 1 for n in out.shape[:-2]):
        raise ValueError(f"expected one probability map, got output of shape {out.shape}")
    return out.reshape(out.shape[-2:])


def occupancy_target(truth_window: np.ndarray) -> np.ndarray:
    """float32 target: 1 for OCCUPIED and exterior (UNKNOWN in the truth) cells, 0 for interior FREE cells."""
    return (truth_window != FREE).astype(np.float32)


def loss_weights(
    truth_window: np.ndarray,
    observed_window: np.ndarray,
    exterior_weight: float,
    observed_weight: float,
    wall_weight: float = 1.0,
) -> np.ndarray:
    """Per-cell BCE weights: 1 for unobserved interior free cells, ``wall_weight`` for unobserved interior occupied
    cells (the structure, a few per cent of a window; issue #17's wall-weighting lever), ``exterior_weight`` for
    unobserved exterior cells, ``observed_weight`` for observed cells (their prediction is never used: the
    observation always wins)."""
    weights = np.where(truth_window == UNKNOWN, np.float32(exterior_weight), np.float32(1.0))
    weights[truth_window == OCCUPIED] = wall_weight
    weights[observed_window != UNKNOWN] = observed_weight
    return weights.astype(np.float32, copy=False)
