"""Post-hoc calibration of the predictor's P(occupied): a strictly increasing map fitted on val (numpy + scipy).

The U-Net's raw probabilities are over-confident on the cells that matter (unobserved interior cells in flight,
docs/predictor/calibration.md): of the cells it calls 0.9 occupied, far fewer than 90 % are. A readers that wants a
probability — the map-only stop rule, an information gain, a risk — needs P(occupied) to mean what it says, so the
card may carry a map ``f`` that :class:`~edge_explorer.predict.predictor.PredictorRuntime` applies to every output.

The map is beta calibration (Kull et al. 2017), ``f(p) = σ(a · ln p − c · ln(1 − p) + b)`` with ``a, c > 0``;
with ``a = c`` it is Platt / temperature scaling on the logit. It is *strictly increasing* (f(0) = 0, f(1) = 1),
which is what keeps every thresholded map unchanged: dynamic thresholding compares the calibrated probabilities with
the mapped thresholds ``f(t)`` (:meth:`ProbabilityCalibration.threshold`, used by
:mod:`edge_explorer.predict.thresholding`), and ``p < t ⇔ f(p) < f(t)``. In float32 two raw values a few ulps apart
could round to the same calibrated value; :func:`order_violations` checks every output level of the int8 model
against every threshold dynamic thresholding can produce, and the fitting command refuses a map that changes one.
An isotonic map is not used for that reason: its flat steps would merge raw values on either side of a threshold.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

CALIBRATION_KEY = "calibration"  # the card's key: {"method", "params", ...} (predict.predictor.card_calibration)
METHODS = ("platt", "beta")
_FIT_EPS = 1.0 / 8192  # probabilities are clipped to [eps, 1 − eps] for the fit's log-likelihood only


@dataclass(frozen=True)
class ProbabilityCalibration:
    """``f(p) = σ(a · ln p − c · ln(1 − p) + b)``, a, c > 0 (``platt``: a = c)."""

    method: str
    a: float
    b: float
    c: float

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown calibration method {self.method!r}; known: {', '.join(METHODS)}")
        if not (self.a > 0 and self.c > 0 and np.isfinite(self.b)):
            raise ValueError(f"a calibration map needs a, c > 0 and a finite b, got a={self.a} b={self.b} c={self.c}")
        if self.method == "platt" and self.a != self.c:
            raise ValueError(f"platt scaling has a = c, got a={self.a} c={self.c}")

    def __call__(self, probabilities: np.ndarray) -> np.ndarray:
        """float32 calibrated probabilities (NaN stays NaN), computed in float64 from any float array."""
        p = np.asarray(probabilities, dtype=np.float64)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            z = self.a * np.log(p) - self.c * np.log1p(-p) + self.b
            out = 1.0 / (1.0 + np.exp(-z))
        return out.astype(np.float32)

    def threshold(self, t: float) -> float:
        """A raw threshold mapped exactly as the probabilities are: float32 in (as numpy compares a float32 map
        with a Python float), float32 out."""
        return float(self(np.float32(t)))

    def to_json(self) -> dict[str, Any]:
        params = {"a": self.a, "b": self.b} if self.method == "platt" else {"a": self.a, "b": self.b, "c": self.c}
        return {
            "method": self.method,
            "params": params,
            "formula": "sigmoid(a*ln(p) - c*ln(1-p) + b)" + (", c = a" if self.method == "platt" else ""),
        }

    @classmethod
    def from_json(cls, entry: Any) -> ProbabilityCalibration:
        """The card's entry; ValueError (or KeyError/TypeError) on a malformed one."""
        method = str(entry["method"])
        params = entry["params"]
        a = float(params["a"])
        return cls(method, a, float(params["b"]), a if method == "platt" else float(params["c"]))


def fit(
    probs: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None, method: str = "beta"
) -> ProbabilityCalibration:
    """The map of ``method`` that maximizes the (weighted) likelihood of binary ``truth`` under ``f(probs)``."""
    from scipy.optimize import minimize

    p = np.clip(np.asarray(probs, dtype=np.float64).ravel(), _FIT_EPS, 1 - _FIT_EPS)
    y = np.asarray(truth, dtype=np.float64).ravel()
    w = np.ones_like(p) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if not p.shape == y.shape == w.shape or w.sum() <= 0:
        raise ValueError("fit needs probs, truth and weights of one shape and a positive total weight")
    w = w / w.sum()
    lp, lq = np.log(p), np.log1p(-p)

    def nll(theta: np.ndarray) -> tuple[float, np.ndarray]:
        a = np.exp(theta[0])
        c = a if method == "platt" else np.exp(theta[2])
        z = a * lp - c * lq + theta[1]
        # −[y log σ(z) + (1 − y) log σ(−z)] = log(1 + e^z) − y z
        loss = float(np.sum(w * (np.logaddexp(0.0, z) - y * z)))
        dz = w * (1.0 / (1.0 + np.exp(-z)) - y)
        grad_a = a * float(np.sum(dz * lp)) if method != "platt" else a * float(np.sum(dz * (lp - lq)))
        grad = [grad_a, float(np.sum(dz))]
        if method != "platt":
            grad.append(-c * float(np.sum(dz * lq)))
        return loss, np.array(grad)

    if method not in METHODS:
        raise ValueError(f"unknown calibration method {method!r}; known: {', '.join(METHODS)}")
    start = np.zeros(2 if method == "platt" else 3)
    result = minimize(nll, start, jac=True, method="L-BFGS-B", bounds=[(-5, 5), (-20, 20), (-5, 5)][: start.size])
    a = float(np.exp(result.x[0]))
    c = a if method == "platt" else float(np.exp(result.x[2]))
    return ProbabilityCalibration(method, round(a, 6), round(float(result.x[1]), 6), round(c, 6))


def order_violations(
    calibration: ProbabilityCalibration, levels: np.ndarray, thresholds: Iterable[float]
) -> list[tuple[float, float]]:
    """The (level, threshold) pairs whose comparison the map changes: ``level < t`` differs from ``f(level) <
    f(t)`` or ``level > t`` from ``f(level) > f(t)``. The raw side is compared in float32 and in float64 (a map on
    the grid is float32 in the daemon, float64 after :func:`~edge_explorer.mapping.ego.unshift`'s NaN fill in the
    simulator), the calibrated side as thresholding compares it. Empty: every thresholded map of a model that emits
    only ``levels`` is the same with and without the map, for these thresholds."""
    raw32 = np.asarray(levels, dtype=np.float32)
    raw64 = raw32.astype(np.float64)
    mapped = calibration(raw32)
    bad: list[tuple[float, float]] = []
    for t in thresholds:
        t32, tc = np.float32(t), calibration.threshold(t)
        below, above = mapped < tc, mapped > tc
        differs = (raw32 < t32) != below
        differs |= (raw32 > t32) != above
        differs |= (raw64 < t) != below
        differs |= (raw64 > t) != above
        bad.extend((float(v), float(t)) for v in raw32[differs])
    return bad
