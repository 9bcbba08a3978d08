"""Calibrating the thresholds of dynamic thresholding (docs/design.md §5) on held-out flights (pure numpy, no torch).

The thresholded prediction claims cells the sensor has not seen: interior cells UNKNOWN in the observed map that
:func:`~edge_explorer.predict.thresholding.thresholded_map` makes FREE or OCCUPIED ("predicted-known" cells). A
planner may choose goals on them (§5), so their correctness matters more than their number. For each candidate pair
(``t_f_max``, ``t_o``) this module measures, at each true-coverage level the samples were taken at,

* **precision**: the share of predicted-known cells whose code equals the truth, pooled over the level's samples;
* **coverage added**: predicted-known cells / N_M (§7), the mean over the level's samples,

and chooses the pair that adds the most coverage (mean over the levels) while its precision at *every* level is at
least the target (a level where the pair claims no cell claims nothing wrong). When no pair meets the target, the
most precise pair (highest worst-level precision) is chosen and :attr:`Calibration.met_target` says so.

The reliability curve bins the predicted probability of the same cells (unobserved interior, all samples) and
gives the observed frequency of OCCUPIED in each bin: a calibrated predictor lies on the diagonal.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.world.grid import OCCUPIED, UNKNOWN

DEFAULT_PRECISION_TARGET = 0.95
# True coverage to sample at: the levels the acceptance and the evaluation report (50, 80, 95 %). Earlier
# levels can be asked for; on the shipped predictor no pair reaches 95 % at 25 % (docs/predictor/calibration.md).
DEFAULT_LEVELS: tuple[float, ...] = (0.5, 0.8, 0.95)
# Candidate grids; both contain the defaults (0.04, 0.94) so the calibrated pair is compared with them exactly.
# t_f_max reaches far: mid-flight the dynamic factor min(1, 10·(area / max area)^4) is often below 0.1. t_o reaches
# 0.998: a confident model's occupied claims at 50 % coverage are < 95 % right even above 0.99 (a widened U-Net,
# docs/predictor/at_scale.md, session 22), and such a model must still be calibratable.
T_F_MAX_CANDIDATES: tuple[float, ...] = (
    *(0.005, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.10, 0.12, 0.15),
    *(0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50, 0.60, 0.70),
)
T_O_CANDIDATES: tuple[float, ...] = (
    *(0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.88, 0.9),
    *(0.92, 0.94, 0.95, 0.96, 0.97, 0.98, 0.99, 0.995, 0.998),
)
RELIABILITY_BINS = 20


def _rounded(value: float | None) -> float | None:
    """Figures in reports and the card: 5 decimals are far below the sampling error."""
    return None if value is None else round(value, 5)


@dataclass(frozen=True)
class CalibrationSample:
    """One partial map of a held-out flight with the predictor's probabilities on the same 0.20 m grid."""

    level: float  # the true coverage (observed share of N_M) the map was taken at
    probabilities: np.ndarray  # float P(occupied) per cell; NaN where there is no prediction
    observed: np.ndarray  # int8 codes of the observed map
    observed_area_m2: float
    truth: np.ndarray  # int8 codes of the ground truth
    interior: np.ndarray  # bool, the building's interior (N_M cells)


@dataclass(frozen=True)
class PairScore:
    """One candidate pair's precision and coverage added per level (keys: the levels)."""

    t_f_max: float
    t_o: float
    precision: Mapping[float, float | None]  # None: the pair claims no cell at that level
    coverage_added: Mapping[float, float]

    @property
    def worst_precision(self) -> float:
        """The lowest precision over the levels (1.0 if the pair claims no cell anywhere)."""
        return min((p for p in self.precision.values() if p is not None), default=1.0)

    @property
    def mean_coverage_added(self) -> float:
        return float(np.mean(list(self.coverage_added.values())))

    def to_json(self) -> dict[str, Any]:
        return {
            "t_f_max": self.t_f_max,
            "t_o": self.t_o,
            "precision": {f"{level:.2f}": _rounded(p) for level, p in self.precision.items()},
            "coverage_added": {f"{level:.2f}": _rounded(c) for level, c in self.coverage_added.items()},
        }


@dataclass(frozen=True)
class Reliability:
    """Predicted probability in equal bins vs the observed frequency of OCCUPIED (None in empty bins)."""

    bin_edges: tuple[float, ...]
    mean_predicted: tuple[float | None, ...]
    occupied_frequency: tuple[float | None, ...]
    cells: tuple[int, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "bin_edges": list(self.bin_edges),
            "mean_predicted": [_rounded(p) for p in self.mean_predicted],
            "occupied_frequency": [_rounded(f) for f in self.occupied_frequency],
            "cells": list(self.cells),
        }


@dataclass(frozen=True)
class Calibration:
    """The chosen thresholds, whether they meet the target, and the evidence (table, reliability curve)."""

    chosen: PairScore
    met_target: bool
    precision_target: float
    levels: tuple[float, ...]
    samples_per_level: Mapping[float, int]
    table: tuple[PairScore, ...]
    reliability: Reliability

    @property
    def thresholds(self) -> ThresholdConfig:
        return ThresholdConfig(t_f_max=self.chosen.t_f_max, t_o=self.chosen.t_o)

    def score_of(self, thresholds: ThresholdConfig) -> PairScore:
        """The table's row of ``thresholds`` (KeyError if it is not a candidate)."""
        for row in self.table:
            if (row.t_f_max, row.t_o) == (thresholds.t_f_max, thresholds.t_o):
                return row
        raise KeyError(f"({thresholds.t_f_max}, {thresholds.t_o}) is not a candidate pair")

    def front(self) -> tuple[PairScore, ...]:
        """The pairs no other pair beats on both worst-level precision and mean coverage added (the trade-off)."""

        def beaten(row: PairScore) -> bool:
            return any(
                other.worst_precision >= row.worst_precision
                and other.mean_coverage_added >= row.mean_coverage_added
                and (other.worst_precision, other.mean_coverage_added) != (row.worst_precision, row.mean_coverage_added)
                for other in self.table
            )

        return tuple(row for row in self.table if not beaten(row))

    def card_entry(self) -> dict[str, Any]:
        """The model card's ``thresholds`` key (read by :func:`edge_explorer.predict.predictor.card_thresholds`); its
        table is the trade-off front, :meth:`to_json` has every pair."""
        return {
            "t_f_max": self.chosen.t_f_max,
            "t_o": self.chosen.t_o,
            "precision_target": self.precision_target,
            "calibration": {**self.to_json(), "table": [row.to_json() for row in self.front()], "table_rows": "front"},
        }

    def to_json(self) -> dict[str, Any]:
        return {
            "rule": "most coverage added (mean over levels) with precision >= target at every level; "
            "otherwise the pair with the highest worst-level precision",
            "met_target": self.met_target,
            "chosen": self.chosen.to_json(),
            "levels": [f"{level:.2f}" for level in self.levels],
            "samples_per_level": {f"{level:.2f}": n for level, n in self.samples_per_level.items()},
            "table": [row.to_json() for row in self.table],
            "reliability": self.reliability.to_json(),
        }


@dataclass(frozen=True)
class _Unobserved:
    """A sample reduced to what thresholding can change: its unobserved interior cells."""

    level: float
    probabilities: np.ndarray  # 1-D
    unknown: np.ndarray  # 1-D, all UNKNOWN: the observed codes of those cells
    truth: np.ndarray  # 1-D
    observed_area_m2: float
    n_m: int


def _unobserved(sample: CalibrationSample) -> _Unobserved:
    shapes = {sample.probabilities.shape, sample.observed.shape, sample.truth.shape, sample.interior.shape}
    if len(shapes) != 1:
        raise ValueError(f"sample arrays differ in shape: {sorted(shapes)}")
    n_m = int(np.count_nonzero(sample.interior))
    if n_m == 0:
        raise ValueError("a sample's interior mask is empty: N_M = 0")
    cells = sample.interior & (sample.observed == UNKNOWN)
    return _Unobserved(
        sample.level,
        sample.probabilities[cells],
        sample.observed[cells],
        sample.truth[cells],
        sample.observed_area_m2,
        n_m,
    )


def score_pair(samples: Sequence[CalibrationSample], thresholds: ThresholdConfig) -> PairScore:
    """Precision and coverage added of ``thresholds`` at each level of ``samples``."""
    return _score([_unobserved(s) for s in samples], thresholds)


def _score(reduced: Sequence[_Unobserved], thresholds: ThresholdConfig) -> PairScore:
    known: dict[float, int] = {}
    correct: dict[float, int] = {}
    added: dict[float, list[float]] = {}
    for s in reduced:
        codes = thresholded_map(s.probabilities, s.unknown, s.observed_area_m2, thresholds)
        claimed = codes != UNKNOWN
        n_known = int(np.count_nonzero(claimed))
        known[s.level] = known.get(s.level, 0) + n_known
        correct[s.level] = correct.get(s.level, 0) + int(np.count_nonzero(claimed & (codes == s.truth)))
        added.setdefault(s.level, []).append(n_known / s.n_m)
    levels = sorted(added)
    return PairScore(
        thresholds.t_f_max,
        thresholds.t_o,
        {level: (correct[level] / known[level] if known[level] else None) for level in levels},
        {level: float(np.mean(added[level])) for level in levels},
    )


def reliability_curve(samples: Sequence[CalibrationSample], bins: int = RELIABILITY_BINS) -> Reliability:
    """Over the unobserved interior cells of all samples: mean predicted probability and frequency of OCCUPIED per
    equal-width probability bin (the last bin includes 1.0; NaN probabilities are left out)."""
    return _reliability([_unobserved(s) for s in samples], bins)


def _reliability(reduced: Sequence[_Unobserved], bins: int) -> Reliability:
    p = np.concatenate([s.probabilities for s in reduced]).astype(np.float64)
    occupied = np.concatenate([s.truth for s in reduced]) == OCCUPIED
    keep = ~np.isnan(p)
    p, occupied = p[keep], occupied[keep]
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(p, edges[1:-1]), 0, bins - 1)
    cells = np.bincount(which, minlength=bins)
    sum_p = np.bincount(which, weights=p, minlength=bins)
    sum_occupied = np.bincount(which, weights=occupied, minlength=bins)
    return Reliability(
        tuple(round(float(e), 6) for e in edges),
        tuple(float(sum_p[b] / cells[b]) if cells[b] else None for b in range(bins)),
        tuple(float(sum_occupied[b] / cells[b]) if cells[b] else None for b in range(bins)),
        tuple(int(c) for c in cells),
    )


def calibrate(
    samples: Sequence[CalibrationSample],
    precision_target: float = DEFAULT_PRECISION_TARGET,
    t_f_max_candidates: Sequence[float] = T_F_MAX_CANDIDATES,
    t_o_candidates: Sequence[float] = T_O_CANDIDATES,
    reliability_bins: int = RELIABILITY_BINS,
) -> Calibration:
    """Score every candidate pair (``t_f_max`` ≤ ``t_o``) on ``samples`` and choose one (see the module docstring).

    Ties are broken towards the more precise pair, then the smaller ``t_f_max`` and the larger ``t_o``."""
    if not samples:
        raise ValueError("calibration needs at least one sample")
    if not 0.0 < precision_target <= 1.0:
        raise ValueError(f"the precision target must be in (0, 1], got {precision_target}")
    reduced = [_unobserved(s) for s in samples]
    pairs = [(f, o) for f in sorted(t_f_max_candidates) for o in sorted(t_o_candidates) if f <= o]
    if not pairs:
        raise ValueError("no candidate pair with t_f_max <= t_o")
    table = tuple(_score(reduced, ThresholdConfig(t_f_max=f, t_o=o)) for f, o in pairs)

    def safest(row: PairScore) -> tuple[float, float, float, float]:
        return (row.worst_precision, row.mean_coverage_added, -row.t_f_max, row.t_o)

    meeting = [row for row in table if row.worst_precision >= precision_target]
    if meeting:
        chosen = max(meeting, key=lambda row: (row.mean_coverage_added, *safest(row)))
    else:
        chosen = max(table, key=safest)
    levels = tuple(sorted({s.level for s in samples}))
    return Calibration(
        chosen=chosen,
        met_target=bool(meeting),
        precision_target=precision_target,
        levels=levels,
        samples_per_level={level: sum(s.level == level for s in samples) for level in levels},
        table=table,
        reliability=_reliability(reduced, reliability_bins),
    )
