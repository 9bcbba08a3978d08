"""Fitting the predictor's probability calibration on the val split (``edge-explorer train calibrate-probabilities``).

Issue #56: P(occupied) per cell should be calibrated. The val split's flights are the evaluation's
(:func:`~edge_explorer.learn.eval_predictor.evaluate_rasters`: same explorer, per-plan seeds, sensor), flown with the
*raw* model; every unobserved interior cell of every scored scan is counted with its probability and truth
(:class:`~edge_explorer.learn.reliability.ProbabilityCounts`), and a strictly increasing map is fitted to them by
maximum likelihood (:func:`~edge_explorer.predict.probability_calibration.fit`; never on test, which stays the
held-out score).

Before the card is written the map is checked not to change any thresholded map
(:func:`~edge_explorer.predict.probability_calibration.order_violations`): every output level of the int8 model
(multiples of 1/256, and every level seen in the flights) against every threshold dynamic thresholding can produce
(the free threshold for each observed area n · 0.04 m² until it saturates at ``t_f_max``, and ``t_o``). If a
float32 rounding would merge a level with a threshold, ``b`` is nudged by 1e-6 steps until none does (the change is
far below the fit's precision). The card gets one key, ``calibration`` (the map, its val figures, the check, the
provenance); ``thresholds`` stay in raw units and the artifacts and their SHA-256 are untouched.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.backends.card import CARD_FILE, CardError, load_card, verify_sha256
from edge_explorer.backends.chain import load_model
from edge_explorer.learn.eval_predictor import evaluate_rasters
from edge_explorer.learn.predictor_flights import DEFAULT_SENSOR
from edge_explorer.learn.reliability import ProbabilityCounts, plot_reliability
from edge_explorer.predict.predictor import PredictorRuntime, card_calibration
from edge_explorer.predict.probability_calibration import (
    CALIBRATION_KEY,
    METHODS,
    ProbabilityCalibration,
    fit,
    order_violations,
)
from edge_explorer.predict.thresholding import ThresholdConfig, free_threshold
from edge_explorer.world.grid import LOW_RES_M

INT8_LEVELS = np.arange(257, dtype=np.float64) / 256  # the int8 model's outputs: multiples of 1/256
MAX_NUDGES = 200


def reachable_thresholds(thresholds: ThresholdConfig) -> list[float]:
    """Every raw threshold dynamic thresholding can use with ``thresholds`` (no calibration map): t_f for each
    observed area of n low-res cells (:meth:`~edge_explorer.mapping.observed.ObservedMaps.observed_area_m2`) until it
    reaches ``t_f_max``, then ``t_f_max`` and ``t_o``."""
    raw = dataclasses.replace(thresholds, calibration=None)
    out: list[float] = []
    n = 0
    while True:
        t_f = free_threshold(float(n) * LOW_RES_M**2, raw)
        out.append(t_f)
        if t_f >= raw.t_f_max:
            break
        n += 1
    return [*out, raw.t_o]


def order_safe(
    calibration: ProbabilityCalibration, levels: np.ndarray, thresholds: list[float]
) -> tuple[ProbabilityCalibration, int]:
    """``calibration``, or the nearest one with ``b`` nudged by 1e-6 steps, that changes no (level, threshold)
    comparison; and the nudge count. Raises ValueError if none within :data:`MAX_NUDGES`."""
    for k in range(MAX_NUDGES + 1):
        step = (k + 1) // 2 * (1 if k % 2 else -1)
        candidate = dataclasses.replace(calibration, b=round(calibration.b + step * 1e-6, 7))
        if not order_violations(candidate, levels, thresholds):
            return candidate, step
    raise ValueError("no nudge of the calibration map keeps every thresholded map unchanged")


def write_card_calibration(card_path: Path, calibration: ProbabilityCalibration, entry: dict[str, Any]) -> None:
    """Add the card's ``calibration`` key (replacing an earlier one); check the card still loads, its artifacts still
    verify and the map reads back."""
    doc = json.loads(card_path.read_text())
    doc[CALIBRATION_KEY] = entry
    card_path.write_text(json.dumps(doc, indent=1) + "\n")
    card = load_card(card_path)
    for artifact in card.artifacts.values():
        verify_sha256(card, artifact)
    if card_calibration(card_path) != calibration:
        raise CardError(f"{card_path}: the calibration written does not read back")


def calibrate_probabilities_cli(args: argparse.Namespace) -> int:
    """``edge-explorer train calibrate-probabilities``: fit on val, check, write the card and the figures."""
    from edge_explorer.cli_support import write_json
    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import regenerate_split

    card_path = args.model / CARD_FILE
    predictor = PredictorRuntime(load_model(card_path), calibrated=False)  # raw output, as the daemon runs it
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=args.occupied_noise)
    t0 = time.perf_counter()
    plans = regenerate_split("val", args.plans)
    rasters = [plan_to_raster(p) for p in plans]
    report = evaluate_rasters(
        f"val (first {args.plans})", rasters, predictor, args.explorer, args.seed, predictor.thresholds, sensor
    )
    counts = ProbabilityCounts.from_json(report["reliability"]["counts"])
    fitted = fit(*counts.samples(), method=args.method)
    ece_by_method = {m: round(counts.reliability(args.bins, fit(*counts.samples(), method=m)).ece, 5) for m in METHODS}
    seen = ProbabilityCounts.grid()[(counts.free + counts.occupied) > 0]
    levels = np.union1d(INT8_LEVELS, seen)
    thresholds = reachable_thresholds(predictor.thresholds)
    calibration, nudge = order_safe(fitted, levels, thresholds)
    before, after = counts.reliability(args.bins), counts.reliability(args.bins, calibration)
    provenance = {
        "command": shlex.join(["edge-explorer", *sys.argv[1:]]),
        "split": "val (regenerated, edge_explorer.world.dataset.regenerate_split)",
        "plans": ",".join(p.name for p in plans),
        "explorer": report["explorer"],
        "seed": args.seed,
        "sensor_occupied_noise_prob": args.occupied_noise,
        "cells": "unobserved interior cells in the window at every scored scan (eval predictor's flights)",
        "engine": predictor.model.report,
        "seconds": round(time.perf_counter() - t0, 1),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    raw_t = predictor.thresholds
    entry = {
        **calibration.to_json(),
        "note": "PredictorRuntime applies the map to every output; 'thresholds' stay raw and are mapped with it "
        "(predict/thresholding.py), so every thresholded map is unchanged",
        "thresholds_mapped": {"t_f_max": calibration.threshold(raw_t.t_f_max), "t_o": calibration.threshold(raw_t.t_o)},
        "order_check": {
            "levels": len(levels),
            "thresholds": len(thresholds),
            "violations": 0,
            "b_nudged_by": round(nudge * 1e-6, 7),
        },
        "val": {
            "bins": args.bins,
            "ece_raw": round(before.ece, 5),
            "ece_calibrated": round(after.ece, 5),
            "mce_raw": round(before.mce, 5),
            "mce_calibrated": round(after.mce, 5),
            "brier_raw": round(before.brier, 5),
            "brier_calibrated": round(after.brier, 5),
            "cells": int(before.n),
            "ece_calibrated_by_method": ece_by_method,
        },
        "provenance": provenance,
    }
    args.docs.mkdir(parents=True, exist_ok=True)
    write_json(
        args.docs / "probability_calibration_val.json",
        {"model": str(args.model), "calibration": entry, "raw": before.to_json(), "calibrated": after.to_json()},
    )
    noise = f"sensor noise {args.occupied_noise:g}" if args.occupied_noise else "no sensor noise"
    plot_reliability(
        {"raw": before, "calibrated": after},
        args.docs / "reliability_val.png",
        f"{args.model.name}, {len(plans)} val plans, {noise}",
    )
    write_card_calibration(card_path, calibration, entry)
    print(
        f"{int(before.n)} cells of {len(plans)} val plans: {calibration.method} map "
        f"{json.dumps(calibration.to_json()['params'])}; ECE {before.ece:.4f} → {after.ece:.4f}, "
        f"MCE {before.mce:.4f} → {after.mce:.4f}, Brier {before.brier:.4f} → {after.brier:.4f}"
    )
    print(
        f"thresholds t_f_max {raw_t.t_f_max:g} → {calibration.threshold(raw_t.t_f_max):.4f}, t_o {raw_t.t_o:g} → "
        f"{calibration.threshold(raw_t.t_o):.4f}; {len(levels)} levels × {len(thresholds)} thresholds keep their "
        f"order (b nudged by {nudge * 1e-6:g}); card: {card_path}"
    )
    return 0
