"""How far the map predictor's probabilities can be trusted: reliability diagram, ECE, MCE, Brier (pure numpy).

Tracker issue #56 asks for a *calibrated* P(occupied) per cell: among the cells the predictor gives 0.7, about 70 %
should be occupied. The measure is the usual one (Guo et al. 2017): the predicted probabilities are put into
``bins`` equal-width bins over [0, 1] (the last bin includes 1.0), and per bin the mean predicted probability is
compared with the observed frequency of OCCUPIED.

* **ECE** (expected calibration error): Σ_b (n_b / N) · |freq_b − conf_b|, bins weighted by their cell count;
* **MCE** (maximum calibration error): max_b |freq_b − conf_b| over the non-empty bins;
* **Brier score**: mean (p − y)², y = 1 for occupied (a proper score: calibration and sharpness together).

The evaluation (:mod:`edge_explorer.learn.eval_predictor`) sees tens of millions of cells, so it does not keep them:
:class:`ProbabilityCounts` counts free and occupied cells per probability on a fine grid of
:data:`GRID_STEPS` steps (exact for the int8 model, whose outputs are multiples of 1/256; within 1.2e-4 for a float
model) and the figures come from those counts as weighted samples.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

DEFAULT_BINS = 20  # as the threshold calibration's reliability curve (predict/calibration.py)
GRID_STEPS = 4096  # ProbabilityCounts: probabilities rounded to multiples of 1/4096 (int8 levels k/256 exactly)


@dataclass(frozen=True)
class Reliability:
    """A reliability diagram (per bin: mean predicted probability, observed frequency of OCCUPIED, weight; None in
    empty bins) and the scores of the same cells."""

    bin_edges: tuple[float, ...]
    mean_predicted: tuple[float | None, ...]
    observed_frequency: tuple[float | None, ...]
    cells: tuple[float, ...]  # the weight (cell count) of each bin
    ece: float
    mce: float
    brier: float
    n: float  # total weight (cells)

    def to_json(self) -> dict[str, Any]:
        def r(v: float | None) -> float | None:
            return None if v is None else round(v, 5)

        return {
            "ece": r(self.ece),
            "mce": r(self.mce),
            "brier": r(self.brier),
            "cells": int(round(self.n)),
            "bins": len(self.cells),
            "bin_edges": [round(e, 6) for e in self.bin_edges],
            "mean_predicted": [r(v) for v in self.mean_predicted],
            "observed_frequency": [r(v) for v in self.observed_frequency],
            "bin_cells": [int(round(c)) for c in self.cells],
        }


def reliability(
    probs: np.ndarray, truth: np.ndarray, bins: int = DEFAULT_BINS, weights: np.ndarray | None = None
) -> Reliability:
    """The reliability diagram and scores of predicted probabilities ``probs`` against binary ``truth`` (True / 1 =
    occupied), each entry weighted by ``weights`` (default 1; counts when the samples are aggregated). NaN
    probabilities (no prediction) are left out. Raises ValueError on mismatched shapes, probabilities outside [0, 1],
    or no sample."""
    if bins < 1:
        raise ValueError(f"need at least one bin, got {bins}")
    p = np.asarray(probs, dtype=np.float64).ravel()
    y = np.asarray(truth, dtype=np.float64).ravel()
    w = np.ones_like(p) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if not p.shape == y.shape == w.shape:
        raise ValueError(f"probs {p.shape}, truth {y.shape} and weights {w.shape} differ")
    keep = ~np.isnan(p)
    p, y, w = p[keep], y[keep], w[keep]
    if np.any((p < 0) | (p > 1)):
        raise ValueError("probabilities must lie in [0, 1]")
    if np.any(w < 0):
        raise ValueError("weights must be non-negative")
    total = float(w.sum())
    if total <= 0:
        raise ValueError("no sample to measure (all NaN, empty, or zero weight)")
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(p, edges[1:-1]), 0, bins - 1)
    n_b = np.bincount(which, weights=w, minlength=bins)
    conf_b = np.bincount(which, weights=w * p, minlength=bins)
    freq_b = np.bincount(which, weights=w * y, minlength=bins)
    full = n_b > 0
    gap = np.zeros(bins)
    gap[full] = np.abs(freq_b[full] - conf_b[full]) / n_b[full]
    return Reliability(
        bin_edges=tuple(float(e) for e in edges),
        mean_predicted=tuple(float(conf_b[b] / n_b[b]) if full[b] else None for b in range(bins)),
        observed_frequency=tuple(float(freq_b[b] / n_b[b]) if full[b] else None for b in range(bins)),
        cells=tuple(float(c) for c in n_b),
        ece=float(np.sum(n_b * gap) / total),
        mce=float(gap[full].max()),
        brier=float(np.sum(w * (p - y) ** 2) / total),
        n=total,
    )


def ece(probs: np.ndarray, truth: np.ndarray, bins: int = DEFAULT_BINS, weights: np.ndarray | None = None) -> float:
    """The expected calibration error of :func:`reliability` (count-weighted mean |frequency − confidence|)."""
    return reliability(probs, truth, bins, weights).ece


@dataclass
class ProbabilityCounts:
    """Free and occupied cells counted per predicted probability, rounded to multiples of 1 / :data:`GRID_STEPS`:
    the sufficient statistics of :func:`reliability` for many cells (and of a calibration fit)."""

    free: np.ndarray = field(default_factory=lambda: np.zeros(GRID_STEPS + 1, dtype=np.int64))
    occupied: np.ndarray = field(default_factory=lambda: np.zeros(GRID_STEPS + 1, dtype=np.int64))

    @staticmethod
    def grid() -> np.ndarray:
        """The probability each count stands for: k / GRID_STEPS, k = 0 … GRID_STEPS."""
        return np.arange(GRID_STEPS + 1, dtype=np.float64) / GRID_STEPS

    def add(self, probs: np.ndarray, occupied: np.ndarray) -> None:
        """Count cells with probabilities ``probs`` (NaN skipped) whose truth is ``occupied`` (bool, same shape)."""
        p = np.asarray(probs, dtype=np.float64).ravel()
        occ = np.asarray(occupied, dtype=bool).ravel()
        if p.shape != occ.shape:
            raise ValueError(f"probs {p.shape} and occupied {occ.shape} differ")
        keep = ~np.isnan(p)
        k = np.clip(np.rint(p[keep] * GRID_STEPS), 0, GRID_STEPS).astype(np.int64)
        occ = occ[keep]
        self.free += np.bincount(k[~occ], minlength=GRID_STEPS + 1)
        self.occupied += np.bincount(k[occ], minlength=GRID_STEPS + 1)

    def merge(self, other: ProbabilityCounts) -> ProbabilityCounts:
        return ProbabilityCounts(self.free + other.free, self.occupied + other.occupied)

    @property
    def total(self) -> int:
        return int(self.free.sum() + self.occupied.sum())

    def samples(
        self, transform: Callable[[np.ndarray], np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(probs, truth, weights) of the non-empty counts, ``transform`` (a calibration map) applied to probs."""
        grid = self.grid()
        p = np.concatenate([grid, grid])
        y = np.concatenate([np.zeros(grid.size), np.ones(grid.size)])
        w = np.concatenate([self.free, self.occupied]).astype(np.float64)
        keep = w > 0
        p, y, w = p[keep], y[keep], w[keep]
        if transform is not None:
            p = np.asarray(transform(p.astype(np.float32)), dtype=np.float64)
        return p, y, w

    def reliability(
        self, bins: int = DEFAULT_BINS, transform: Callable[[np.ndarray], np.ndarray] | None = None
    ) -> Reliability:
        probs, truth, weights = self.samples(transform)
        return reliability(probs, truth, bins, weights)

    def to_json(self) -> dict[str, Any]:
        """Sparse: the non-empty grid steps and their counts."""
        nz = np.flatnonzero(self.free + self.occupied)
        return {
            "grid_steps": GRID_STEPS,
            "k": nz.tolist(),
            "free": self.free[nz].tolist(),
            "occupied": self.occupied[nz].tolist(),
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> ProbabilityCounts:
        if int(doc["grid_steps"]) != GRID_STEPS:
            raise ValueError(f"counts on a grid of {doc['grid_steps']} steps, this module uses {GRID_STEPS}")
        counts = cls()
        k = np.asarray(doc["k"], dtype=np.int64)
        counts.free[k] = np.asarray(doc["free"], dtype=np.int64)
        counts.occupied[k] = np.asarray(doc["occupied"], dtype=np.int64)
        return counts


def plot_reliability(curves: dict[str, Reliability], path: Any, title: str) -> None:
    """Reliability diagram of one or more :class:`Reliability` (label → curve) with the cell share per bin below.
    Small PNG (docs keep it under 200 kB)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_n) = plt.subplots(2, 1, figsize=(5.2, 6.0), height_ratios=(3, 1), sharex=True, constrained_layout=True)
    ax.plot([0, 1], [0, 1], ":", color="0.5", label="perfectly calibrated")
    for k, (label, rel) in enumerate(curves.items()):
        conf = np.array([np.nan if v is None else v for v in rel.mean_predicted])
        freq = np.array([np.nan if v is None else v for v in rel.observed_frequency])
        ax.plot(conf, freq, "o-", ms=4, label=f"{label}: ECE {rel.ece:.3f}, MCE {rel.mce:.3f}, Brier {rel.brier:.3f}")
        edges = np.array(rel.bin_edges)
        share = np.array(rel.cells) / rel.n
        width = (edges[1] - edges[0]) / (len(curves) + 1)
        ax_n.bar(edges[:-1] + width * (k + 0.5), share, width=width, align="edge", label=label)
    ax.set(xlim=(0, 1), ylim=(0, 1), ylabel="observed frequency of OCCUPIED", title=title)
    ax.legend(loc="upper left", fontsize=7)
    ax_n.set(xlabel="predicted P(occupied)", ylabel="share of cells", yscale="log")
    fig.savefig(path, dpi=90)
    plt.close(fig)
