"""Calibrating the shipped predictor's thresholds on the val split (``edge-explorer train calibrate-predictor``).

The samples come from the evaluation's flights (:func:`~edge_explorer.learn.eval_predictor.predictions_in_flight`:
same explorer, same per-plan seeds, same sensor): on each plan of the regenerated val split — never the test split,
which stays the held-out score — the partial map, the prediction on it and the truth are kept at the first scan
whose true coverage reaches each calibration level, and the flight stops once the last level is taken.
:func:`~edge_explorer.predict.calibration.calibrate` then chooses ``t_f_max`` and ``t_o`` for the precision target.

A separate ``train`` command rather than an ``eval predictor`` option: it writes the shipped model card, as
``ship-predictor`` does, and it is tied to the val split, while ``eval predictor`` only reads a model and scores it on
any plans. The card gets one key, ``thresholds`` (the chosen pair, the target, the table, the reliability curve and
the provenance), and only when the chosen pair meets the target; the artifacts and their SHA-256 are untouched, and
the card is checked to load and verify afterwards. The figures go to ``docs/predictor/`` either way.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.backends.card import CARD_FILE, CardError, load_card, verify_sha256
from edge_explorer.backends.chain import load_model
from edge_explorer.learn.eval_predictor import DEFAULT_THRESHOLDS, make_explorer, predictions_in_flight
from edge_explorer.learn.predictor_flights import DEFAULT_SENSOR, Explorer, Scene
from edge_explorer.predict.calibration import DEFAULT_LEVELS, Calibration, CalibrationSample, calibrate
from edge_explorer.predict.predictor import THRESHOLDS_KEY, PredictorRuntime, card_thresholds
from edge_explorer.sim.env import Predictor
from edge_explorer.vehicle.sensor import SensorConfig


def plan_samples(
    scene: Scene,
    predictor: Predictor,
    explorer: Explorer,
    rng: np.random.Generator,
    levels: Sequence[float] = DEFAULT_LEVELS,
    sensor: SensorConfig = DEFAULT_SENSOR,
) -> list[CalibrationSample]:
    """One flight's samples: at the first predicted scan reaching each level (fewer if the flight ends before)."""
    pending = sorted(levels)
    samples: list[CalibrationSample] = []
    for s, on_map in predictions_in_flight(scene, predictor, explorer, rng, sensor=sensor):
        if on_map is None:
            continue
        while pending and s.coverage >= pending[0] - 1e-9:
            level = pending.pop(0)
            observed = s.maps.low.copy()  # the flight's live map: keep a copy
            area = s.maps.observed_area_m2()
            samples.append(CalibrationSample(level, on_map, observed, area, scene.truth_low, scene.interior_low))
        if not pending:
            break
    return samples


def collect_samples(
    predictor: Predictor,
    n_plans: int,
    explorer_name: str = "random-goal",
    seed: int = 0,
    levels: Sequence[float] = DEFAULT_LEVELS,
    sensor: SensorConfig = DEFAULT_SENSOR,
    split: str = "val",
) -> tuple[list[str], list[CalibrationSample]]:
    """The first ``n_plans`` plans of the regenerated ``split`` (plan ``k`` flies with the seed sequence (seed, k), as
    in the evaluation) and their samples. Thresholds are chosen on val; other splits are for held-out checks."""
    from tqdm import tqdm

    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import regenerate_split

    plans = regenerate_split(split, n_plans)
    samples: list[CalibrationSample] = []
    for k, plan in enumerate(tqdm(plans, desc="calibrate predictor", unit="plan")):
        scene = Scene.from_raster(plan_to_raster(plan))
        rng = np.random.default_rng([seed, k])
        samples.extend(plan_samples(scene, predictor, make_explorer(explorer_name), rng, levels, sensor))
    return [p.name for p in plans], samples


def write_card_thresholds(card_path: Path, calibration: Calibration, provenance: dict[str, Any]) -> None:
    """Add the card's ``thresholds`` key (replacing an earlier one) and check that the card still loads, its artifacts
    still verify and the thresholds read back."""
    doc = json.loads(card_path.read_text())
    doc[THRESHOLDS_KEY] = {**calibration.card_entry(), "provenance": provenance}
    card_path.write_text(json.dumps(doc, indent=1) + "\n")
    card = load_card(card_path)
    for artifact in card.artifacts.values():
        verify_sha256(card, artifact)
    read_back = card_thresholds(card_path)
    if (read_back.t_f_max, read_back.t_o) != (calibration.thresholds.t_f_max, calibration.thresholds.t_o):
        raise CardError(f"{card_path}: the thresholds written do not read back")


def plot_calibration(calibration: Calibration, path: Path, title: str) -> None:
    """Reliability curve, and coverage added vs worst-level precision of every candidate pair."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_rel, ax_pairs) = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
    rel = calibration.reliability
    predicted = np.array([np.nan if v is None else v for v in rel.mean_predicted], dtype=float)
    observed = np.array([np.nan if v is None else v for v in rel.occupied_frequency], dtype=float)
    ax_rel.plot([0, 1], [0, 1], ":", color="0.5", label="calibrated")
    ax_rel.plot(predicted, observed, "o-", label="predictor")
    ax_rel.set(
        xlabel="predicted P(occupied), bin mean",
        ylabel="observed frequency of OCCUPIED",
        xlim=(0, 1),
        ylim=(0, 1),
        title="reliability (unobserved interior cells)",
    )
    ax_rel.legend(loc="upper left")
    worst = np.array([row.worst_precision for row in calibration.table])
    added = np.array([row.mean_coverage_added for row in calibration.table]) * 100
    ax_pairs.scatter(worst, added, s=10, color="0.6", label="candidate (t_f_max, t_o)")
    default = calibration.score_of(DEFAULT_THRESHOLDS)
    for row, marker, name in ((default, "s", "default"), (calibration.chosen, "*", "chosen")):
        ax_pairs.scatter(
            row.worst_precision,
            row.mean_coverage_added * 100,
            s=120,
            marker=marker,
            label=f"{name} ({row.t_f_max:g}, {row.t_o:g})",
        )
    ax_pairs.axvline(calibration.precision_target, color="r", lw=0.8, label="precision target")
    levels = ", ".join(f"{level:.0%}" for level in calibration.levels)
    ax_pairs.set(
        xlabel=f"precision of predicted-known cells, worst level ({levels})",
        ylabel="coverage added, mean over levels (%)",
        title="threshold pairs",
    )
    ax_pairs.legend(loc="upper left", fontsize=8)
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fmt(precision: float | None) -> str:
    return "  —  " if precision is None else f"{precision:.3f}"


def calibrate_cli(args: argparse.Namespace) -> int:
    """``edge-explorer train calibrate-predictor``: 0 when the card was written, 1 when no pair met the target."""
    from edge_explorer.cli_support import write_json

    card_path = args.model / CARD_FILE
    # as the daemon runs it (the backend chain, int8 first), raw: the thresholds are chosen in raw units
    predictor = PredictorRuntime(load_model(card_path), calibrated=False)
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=args.occupied_noise)
    t0 = time.perf_counter()
    plans, samples = collect_samples(predictor, args.plans, args.explorer, args.seed, args.levels, sensor)
    calibration = calibrate(samples, args.target)
    provenance = {
        "command": shlex.join(["edge-explorer", *sys.argv[1:]]),
        "split": "val (regenerated, edge_explorer.world.dataset.regenerate_split)",
        "plans": ",".join(plans),
        "explorer": make_explorer(args.explorer).name,
        "seed": args.seed,
        "sensor_occupied_noise_prob": args.occupied_noise,
        "engine": predictor.model.report,
        "seconds": round(time.perf_counter() - t0, 1),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    default = calibration.score_of(DEFAULT_THRESHOLDS)
    report = {
        "model": str(args.model),
        "precision_target": args.target,
        "thresholds": {"t_f_max": calibration.chosen.t_f_max, "t_o": calibration.chosen.t_o},
        "default": default.to_json(),
        **calibration.to_json(),
        "provenance": provenance,
        "card_written": calibration.met_target,
    }
    args.docs.mkdir(parents=True, exist_ok=True)
    write_json(args.docs / "calibration_val.json", report)
    title = f"{args.model} on {len(plans)} val plans ({provenance['explorer']}), target {args.target:.0%}"
    plot_calibration(calibration, args.docs / "calibration_val.png", title)
    if calibration.met_target:
        write_card_thresholds(card_path, calibration, provenance)
    chosen = calibration.chosen
    verdict = "meets the target" if calibration.met_target else "NO pair meets the target; the most precise one"
    print(f"{len(samples)} samples from {len(plans)} val plans; chosen pair {verdict} ({args.target:.0%}):")
    print(f"  level: precision, coverage added — chosen ({chosen.t_f_max:g}, {chosen.t_o:g}) vs default (0.04, 0.94)")
    for level in calibration.levels:
        print(
            f"  {level:4.0%}: {_fmt(chosen.precision[level])}, +{chosen.coverage_added[level]:.3f}"
            f" — {_fmt(default.precision[level])}, +{default.coverage_added[level]:.3f}"
            f"  (n={calibration.samples_per_level[level]})"
        )
    print(f"card: {'thresholds written to ' + str(card_path) if calibration.met_target else 'not written'}")
    return 0 if calibration.met_target else 1
