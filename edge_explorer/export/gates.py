"""Accuracy gates: a quantized artifact against fp32 torch on the held-back observations.

* **Predictor** — what the planner consumes is the *thresholded* map, so that is what is compared. For every
  held-back observation both probability maps go back onto the plan's 0.20 m map
  (:func:`~edge_explorer.mapping.ego.unshift`), through dynamic thresholding
  (:func:`~edge_explorer.predict.thresholding.thresholded_map`, default t_f_max / t_o, the observation's own
  observed area), and are scored (docs/design.md §7 F1 against the plan's truth).
  ``f1_drop`` = mean F1 (fp32) − mean F1 (candidate); ``cell_agreement`` = the share of the building's
  *unobserved interior* cells — the cells the prediction decides and the §7 metrics count (N_M) — that get the same
  code from both. Observed cells always agree, so counting them would only dilute the figure; cells outside the
  building are never flown nor scored. Both are reported beside it, not gated: ``unobserved_cell_agreement``
  (every unobserved cell of the plan's grid, exterior included) and ``interior_cell_agreement`` (all N_M cells of
  M_thres, observed ones included).
* **Goal policy** — ``top1_agreement``: the share of held-back decisions where both choose the same goal, each
  choosing the argmax over that decision's *valid* goal cells only (:func:`masked_argmax`, what the planner flies):
  a disagreement at a masked cell changes nothing in flight and does not count. Reported beside it, not gated:
  ``unmasked_top1_agreement`` (argmax over all 59 × 59 cells) and ``mean_valid_cells`` per decision.

Every artifact also reports ``max_abs_diff`` of its raw output against torch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge_explorer.export.calibration import MapSample
from edge_explorer.mapping.ego import unshift
from edge_explorer.mapping.metrics import map_metrics
from edge_explorer.predict.encoding import decode_probabilities
from edge_explorer.predict.thresholding import thresholded_map
from edge_explorer.world.grid import UNKNOWN


@dataclass(frozen=True)
class GateResult:
    passed: bool
    figures: dict[str, float]
    summary: str  # the table's "Accuracy vs fp32" cell
    failures: tuple[str, ...] = ()


def predictor_gate(
    reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray], maps: Sequence[MapSample], gates: Mapping
) -> GateResult:
    """F1 drop and cell agreement after dynamic thresholding (see the module docstring)."""
    f1_ref, f1_cand = [], []
    counts = {"gated": [0, 0], "unobserved": [0, 0], "interior": [0, 0]}  # [agreeing cells, cells]
    for p_ref, p_cand, m in zip(reference, candidate, maps, strict=True):
        codes = []
        for p in (p_ref, p_cand):
            on_map = unshift(decode_probabilities(p), m.robot_cell, m.observed_low.shape)
            codes.append(thresholded_map(on_map, m.observed_low, m.observed_area_m2))
        f1_ref.append(map_metrics(m.observed_low, m.truth_low, m.interior_low, codes[0]).f1)
        f1_cand.append(map_metrics(m.observed_low, m.truth_low, m.interior_low, codes[1]).f1)
        unobserved = m.observed_low == UNKNOWN
        same = codes[0] == codes[1]
        for key, cells in (
            ("gated", unobserved & m.interior_low),
            ("unobserved", unobserved),
            ("interior", m.interior_low),
        ):
            counts[key][0] += int(np.count_nonzero(same[cells]))
            counts[key][1] += int(np.count_nonzero(cells))
    figures = {
        "f1_fp32": float(np.mean(f1_ref)),
        "f1": float(np.mean(f1_cand)),
        "f1_drop": float(np.mean(f1_ref) - np.mean(f1_cand)),
        "cell_agreement": counts["gated"][0] / max(counts["gated"][1], 1),
        "unobserved_cell_agreement": counts["unobserved"][0] / max(counts["unobserved"][1], 1),
        "interior_cell_agreement": counts["interior"][0] / max(counts["interior"][1], 1),
        "max_abs_diff": _max_abs_diff(reference, candidate),
        "observations": len(maps),
    }
    failures = []
    if figures["f1_drop"] > gates["max_f1_drop"]:
        failures.append(f"F1 drop {figures['f1_drop']:.4f} > {gates['max_f1_drop']}")
    if figures["cell_agreement"] < gates["min_cell_agreement"]:
        failures.append(f"cell agreement {figures['cell_agreement']:.4f} < {gates['min_cell_agreement']}")
    summary = f"F1 {figures['f1']:.3f} (Δ {-figures['f1_drop']:+.4f}), cells agree {figures['cell_agreement']:.2%}"
    return GateResult(not failures, figures, summary, tuple(failures))


def masked_argmax(scores: np.ndarray, mask: np.ndarray) -> int:
    """The flat index of the highest score among the cells where ``mask`` is True (the mask must have one)."""
    return int(np.argmax(np.where(np.asarray(mask, bool).ravel(), np.asarray(scores).ravel(), -np.inf)))


def goal_gate(
    reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray], masks: Sequence[np.ndarray], gates: Mapping
) -> GateResult:
    """Masked top-1 goal agreement with fp32 (see the module docstring)."""
    pairs = list(zip(reference, candidate, masks, strict=True))
    same = [masked_argmax(r, m) == masked_argmax(c, m) for r, c, m in pairs]
    figures = {
        "top1_agreement": float(np.mean(same)),
        "unmasked_top1_agreement": float(np.mean([int(np.argmax(r)) == int(np.argmax(c)) for r, c, _ in pairs])),
        "mean_valid_cells": float(np.mean([np.count_nonzero(m) for m in masks])),
        "max_abs_diff": _max_abs_diff(reference, candidate),
        "observations": len(same),
    }
    failures = []
    if figures["top1_agreement"] < gates["min_top1_agreement"]:
        failures.append(f"masked top-1 goal agreement {figures['top1_agreement']:.4f} < {gates['min_top1_agreement']}")
    summary = f"goal agree {figures['top1_agreement']:.2%} of {len(same)}"
    return GateResult(not failures, figures, summary, tuple(failures))


def parity_gate(reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray], tolerance: float) -> GateResult:
    """fp32 export parity: the largest raw output difference against torch must stay within ``tolerance``."""
    diff = _max_abs_diff(reference, candidate)
    failures = () if diff <= tolerance else (f"max |Δ| vs torch {diff:.2e} > {tolerance:.0e}",)
    return GateResult(not failures, {"max_abs_diff": diff}, f"max |Δ| vs torch {diff:.1e}", failures)


def _max_abs_diff(reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray]) -> float:
    return float(max(np.max(np.abs(np.asarray(r) - np.asarray(c))) for r, c in zip(reference, candidate, strict=True)))
