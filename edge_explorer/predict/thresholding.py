"""Dynamic thresholding of the predictor's occupancy probabilities (docs/design.md §5; pure numpy, no torch).

    f_t(m) = FREE if m < t_f, OCCUPIED if m > t_o, else UNKNOWN
    t_f    = t_f_max · min(1, 10 · (observed area / max floor-plan area)^4)

Early in a flight little is observed, so t_f is near 0 and almost nothing is predicted free: a confident but
wrong "free" would send the vehicle towards walls it has not seen. As the observed area grows the free threshold
opens up to ``t_f_max``. Observed cells always keep their observed state; NaN probabilities (no prediction for
that cell) stay UNKNOWN.

**Beyond the training envelope** (issue #55). The predictor learned on buildings of at most 21 × 11 m, whose
unseen surroundings are outside the building; in a whole floor it paints the unseen rest of the building solid.
Measured on a generated 48 × 47 m val floor after 39 m of Nearest Frontier: 32,100 cells predicted occupied, 92 %
of them wrong (free in truth), and 30 % wrong even within 1 m of an observed cell, most with calibrated p ≥ 0.9, so
no confidence threshold separates them; its free predictions there were 4 % wrong. So once the observed cells span
more than the envelope (``envelope_m``: the 21 × 11 m footprint plus 2 m, long side and short side of their
bounding box, :func:`observed_extent_m`) no predicted cell is OCCUPIED. The observed extent is the flight's own
evidence (the plan's size is never read), and it cannot exceed the envelope in a building that fits it, so every
flight inside the envelope is unchanged. A model that learned whole floors predicts there instead
(:class:`~edge_explorer.predict.predictor.PredictorRuntime`'s ``beyond``): the config then carries that model's own
thresholds as ``beyond``, and beyond the envelope its output is thresholded with them, OCCUPIED included.

``t_f_max`` and ``t_o`` are in the units of the model's *raw* output, the probabilities they were chosen on
(``train calibrate-predictor``). When the model's card also calibrates the probabilities
(:mod:`edge_explorer.predict.probability_calibration`, issue #56), the config carries that strictly increasing map
``f`` and the thresholds are mapped through it after the dynamic free threshold is formed — ``f(t_f_max · factor)``,
not ``f(t_f_max) · factor`` — so the calibrated probabilities are cut where the raw ones were and the thresholded
map is the same cell for cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_explorer.predict.probability_calibration import ProbabilityCalibration
from edge_explorer.world.grid import CELL_DTYPE, FREE, LOW_RES_M, OCCUPIED, UNKNOWN

MAX_PLAN_AREA_M2 = 21.0 * 11.0  # the dataset's footprint envelope
ENVELOPE_M = (21.0 + 2.0, 11.0 + 2.0)  # (long, short) sides: the footprint the predictor learned on, plus 2 m


@dataclass(frozen=True)
class ThresholdConfig:
    """Thresholds of f_t; phase-2 training anneals them from (≈0, ≈1) to the defaults. ``calibration``: the map
    the probabilities being thresholded went through (None: raw probabilities); the thresholds stay raw."""

    t_f_max: float = 0.04
    t_o: float = 0.94
    max_plan_area_m2: float = MAX_PLAN_AREA_M2
    calibration: ProbabilityCalibration | None = None
    envelope_m: tuple[float, float] = ENVELOPE_M  # (long, short): beyond it no cell is predicted OCCUPIED…
    beyond: ThresholdConfig | None = None  # … unless a whole-floor model predicts there: its thresholds

    def __post_init__(self) -> None:
        if not 0.0 <= self.t_f_max <= self.t_o <= 1.0:
            raise ValueError(f"need 0 ≤ t_f_max ≤ t_o ≤ 1, got t_f_max={self.t_f_max}, t_o={self.t_o}")
        if not self.max_plan_area_m2 > 0:
            raise ValueError(f"max_plan_area_m2 must be positive, got {self.max_plan_area_m2}")
        if not self.envelope_m[0] >= self.envelope_m[1] > 0:
            raise ValueError(f"envelope_m must be (long, short) with long ≥ short > 0, got {self.envelope_m}")


def free_threshold(observed_area_m2: float, config: ThresholdConfig = ThresholdConfig()) -> float:
    """t_f = t_f_max · min(1, 10 · (observed area / max floor-plan area)^4), through the config's calibration map."""
    ratio = max(observed_area_m2, 0.0) / config.max_plan_area_m2
    t_f = config.t_f_max * min(1.0, 10.0 * ratio**4)
    return t_f if config.calibration is None else config.calibration.threshold(t_f)


def occupied_threshold(config: ThresholdConfig = ThresholdConfig()) -> float:
    """t_o, through the config's calibration map."""
    return config.t_o if config.calibration is None else config.calibration.threshold(config.t_o)


def threshold_probabilities(probabilities: np.ndarray, t_f: float, t_o: float) -> np.ndarray:
    """f_t: int8 codes FREE where p < t_f, OCCUPIED where p > t_o, UNKNOWN elsewhere (and where p is NaN)."""
    codes = np.full(probabilities.shape, UNKNOWN, dtype=CELL_DTYPE)
    with np.errstate(invalid="ignore"):
        codes[probabilities < t_f] = FREE
        codes[probabilities > t_o] = OCCUPIED
    return codes


def observed_extent_m(observed_codes: np.ndarray, resolution_m: float = LOW_RES_M) -> tuple[float, float]:
    """(long, short) sides in metres of the bounding box of the observed (not UNKNOWN) cells; (0, 0) if none."""
    known = observed_codes != UNKNOWN
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if len(rows) == 0:
        return 0.0, 0.0
    height, width = (rows[-1] - rows[0] + 1) * resolution_m, (cols[-1] - cols[0] + 1) * resolution_m
    return max(height, width), min(height, width)


def beyond_envelope(observed_codes: np.ndarray, config: ThresholdConfig, resolution_m: float = LOW_RES_M) -> bool:
    """Whether the observed cells span more than the predictor's training envelope (module docstring)."""
    long_m, short_m = observed_extent_m(observed_codes, resolution_m)
    return long_m > config.envelope_m[0] or short_m > config.envelope_m[1]


def thresholded_map(
    probabilities: np.ndarray,
    observed_codes: np.ndarray,
    observed_area_m2: float,
    config: ThresholdConfig = ThresholdConfig(),
    resolution_m: float = LOW_RES_M,
) -> np.ndarray:
    """M_thres: observed cells as observed, the others f_t of the prediction with the dynamic free threshold; once
    the observed cells of a 2-D map (on a ``resolution_m`` grid) span more than the envelope, the config's ``beyond``
    thresholds (a whole-floor model's output) or, without them, no predicted OCCUPIED (a flat selection of cells, as
    calibration scores them, has no extent: it is thresholded as within)."""
    if probabilities.shape != observed_codes.shape:
        raise ValueError(f"probabilities {probabilities.shape} and observed map {observed_codes.shape} differ")
    beyond = observed_codes.ndim == 2 and beyond_envelope(observed_codes, config, resolution_m)
    used = config.beyond if beyond and config.beyond is not None else config
    predicted = threshold_probabilities(probabilities, free_threshold(observed_area_m2, used), occupied_threshold(used))
    if beyond and config.beyond is None:
        predicted[predicted == OCCUPIED] = UNKNOWN
    return np.where(observed_codes != UNKNOWN, observed_codes, predicted)
