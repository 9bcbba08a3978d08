"""Evaluating the map predictor the paper's way: map quality with the prediction against the true coverage.

Each plan is explored once by a fixed-seed explorer of :mod:`edge_explorer.learn.predictor_flights` (the prediction
does not steer the flight). At every scan that enters a new 0.5 % bin of true coverage (observed cells only), the
predictor reads the north-up ego window, the probabilities go back onto the map (:func:`~edge_explorer.mapping.ego.
unshift`), dynamic thresholding (docs/design.md §5) fills the unobserved cells, and the map is scored (§7): F1, coverage
and correct coverage of observed + thresholded prediction, beside the F1 of the observed map alone and the F1 a
perfect prediction would reach (``f1_ceiling``: every unobserved cell right). The ceiling is below 1 because observed
cells always win and some are wrong — sensor noise marks free cells beside walls occupied (docs/design.md §6).
Every reported level (50, 80, 95, 98 %) is a bin edge, so "F1 at 80 %" is exactly the first scan whose true
coverage reaches 80 %.

Reliability (issue #56, :mod:`edge_explorer.learn.reliability`): at the same scored scans, every unobserved interior
cell inside the predictor's window is counted with its probability and its truth — the cells the prediction speaks
for in flight — and the report gives the reliability diagram, ECE, MCE and Brier score over them: of the model's raw
output (``reliability.raw``) and, when its card calibrates the probabilities, of what the runtime hands out
(``reliability.calibrated``). The flight flies the raw model and thresholds it with the raw thresholds, which gives
the very maps the calibrated model and its mapped thresholds give (:mod:`edge_explorer.predict.thresholding`).
Early scans have more unobserved cells, so they weigh more.

Aggregation: per coverage level, the mean over the plans whose flight reached it (``n`` says how many did: the
inside of tall furniture is never observable, so not every plan reaches 98 % true coverage).

The predictor is any ``Callable[[int8 256×256 window], float32 probabilities]`` (:data:`edge_explorer.sim.env.
Predictor`), loaded by :func:`edge_explorer.learn.loaders.load_predictor`: the torch weights
(:class:`~edge_explorer.learn.unet.TorchPredictor`) or an exported model folder (ONNX / TFLite through the backend
chain, exactly what the daemon runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_explorer.backends.card import CARD_FILE
from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.predictor_flights import (
    DEFAULT_SENSOR,
    Explorer,
    FlightLimits,
    FlightStep,
    PlannerExplorer,
    RandomGoalWalk,
    Scene,
    fly,
)
from edge_explorer.learn.reliability import DEFAULT_BINS, ProbabilityCounts, plot_reliability
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS, pad_shift, unshift
from edge_explorer.mapping.metrics import map_metrics
from edge_explorer.predict.predictor import PredictorRuntime, thresholds_of
from edge_explorer.predict.probability_calibration import ProbabilityCalibration
from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.sim.env import Predictor
from edge_explorer.vehicle.sensor import SensorConfig
from edge_explorer.world.grid import OCCUPIED, UNKNOWN
from edge_explorer.world.raster import PlanRaster

REPORT_LEVELS: tuple[float, ...] = (0.5, 0.8, 0.95, 0.98)
BIN_WIDTH = 0.005  # a scan is scored when its true coverage enters a new bin of this width
CURVE_LEVELS = np.round(np.arange(0.01, 1.0001, 0.01), 2)
SERIES = ("f1", "coverage", "correct_coverage", "f1_observed", "f1_ceiling")
DEFAULT_THRESHOLDS = ThresholdConfig()  # t_f_max 0.04, t_o 0.94 (docs/design.md §5)
# Fly on until the coverage has not grown for 600 scans (scans are cheap; the predictor runs once per 0.5 % bin):
# with the training data's patience (150) few flights reach 98 % true coverage.
EVAL_LIMITS = FlightLimits(max_steps=4000, stall_steps=600)


def make_explorer(name: str) -> Explorer:
    """``random-goal`` (the frontier-seeking :class:`RandomGoalWalk`), or a planner: ``frontier``, ``fuel``."""
    if name == "random-goal":
        return RandomGoalWalk(greedy_prob=0.8)
    if name in ("frontier", "fuel"):
        return PlannerExplorer(name)
    raise EdgeExplorerError(f"unknown explorer {name!r}; choose random-goal, frontier or fuel")


@dataclass(frozen=True)
class PlanCurve:
    """One flight's scored scans, in order: true coverage and the series of :data:`SERIES`."""

    name: str
    true_coverage: np.ndarray
    series: dict[str, np.ndarray]
    steps: int
    counts: ProbabilityCounts = dataclasses.field(default_factory=ProbabilityCounts)  # unobserved interior cells

    def at(self, level: float) -> dict[str, float] | None:
        """The scores at the first scored scan whose true coverage reaches ``level``; None if never reached."""
        reached = np.flatnonzero(self.true_coverage >= level - 1e-9)
        if reached.size == 0:
            return None
        return {key: float(values[reached[0]]) for key, values in self.series.items()}


def predictions_in_flight(
    scene: Scene,
    predictor: Predictor,
    explorer: Explorer,
    rng: np.random.Generator,
    limits: FlightLimits = EVAL_LIMITS,
    sensor: SensorConfig = DEFAULT_SENSOR,
) -> Iterator[tuple[FlightStep, np.ndarray | None]]:
    """Fly one plan; every scan with the prediction on the 0.20 m map (NaN outside the window) when its true
    coverage enters a new :data:`BIN_WIDTH` bin, None otherwise."""
    last_bin = -1
    for s in fly(scene, explorer, rng, sensor, limits):
        coverage_bin = math.floor(s.coverage / BIN_WIDTH + 1e-9)
        if coverage_bin == last_bin:
            yield s, None
            continue
        last_bin = coverage_bin
        cell = scene.low_cell(s.pose[0], s.pose[1])
        probabilities = predictor(pad_shift(s.maps.low, cell, PREDICTOR_WINDOW_CELLS))
        yield s, unshift(np.asarray(probabilities, dtype=np.float32), cell, s.maps.low.shape)


def evaluate_plan(
    scene: Scene,
    predictor: Predictor,
    explorer: Explorer,
    rng: np.random.Generator,
    thresholds: ThresholdConfig = DEFAULT_THRESHOLDS,
    limits: FlightLimits = EVAL_LIMITS,
    sensor: SensorConfig = DEFAULT_SENSOR,
) -> PlanCurve:
    """Fly one plan and score the map with the thresholded prediction at each new coverage bin."""
    true_coverage: list[float] = []
    series: dict[str, list[float]] = {key: [] for key in SERIES}
    counts = ProbabilityCounts()
    steps = 0
    for s, on_map in predictions_in_flight(scene, predictor, explorer, rng, limits, sensor):
        steps = s.step + 1
        if on_map is None:
            continue
        maps = s.maps
        thres = thresholded_map(on_map, maps.low, maps.observed_area_m2(), thresholds)
        m = map_metrics(maps.low, scene.truth_low, scene.interior_low, thres)
        unseen = scene.interior_low & (maps.low == UNKNOWN)
        counts.add(on_map[unseen], scene.truth_low[unseen] == OCCUPIED)
        true_coverage.append(s.coverage)
        series["f1"].append(m.f1)
        series["coverage"].append(m.coverage)
        series["correct_coverage"].append(m.correct_coverage)
        series["f1_observed"].append(map_metrics(maps.low, scene.truth_low, scene.interior_low).f1)
        series["f1_ceiling"].append(map_metrics(maps.low, scene.truth_low, scene.interior_low, scene.truth_low).f1)
    return PlanCurve(scene.name, np.array(true_coverage), {k: np.array(v) for k, v in series.items()}, steps, counts)


def reliability_report(
    curves: Sequence[PlanCurve], calibration: ProbabilityCalibration | None, bins: int = DEFAULT_BINS
) -> dict:
    """The reliability of the raw probabilities and, with ``calibration``, of the calibrated ones, over the
    unobserved interior cells of every scored scan; with the counts they come from (a fit can start from them)."""
    counts = functools.reduce(ProbabilityCounts.merge, (c.counts for c in curves), ProbabilityCounts())
    report: dict = {"cells": "unobserved interior cells in the window, every scored scan", "bins": bins}
    if counts.total == 0:
        return {**report, "raw": None, "calibrated": None, "counts": counts.to_json()}
    report["raw"] = counts.reliability(bins).to_json()
    report["calibrated"] = None if calibration is None else counts.reliability(bins, calibration).to_json()
    report["calibration"] = None if calibration is None else calibration.to_json()
    return {**report, "counts": counts.to_json()}


def summarize(curves: Sequence[PlanCurve]) -> dict:
    """Per level: mean of each series over the plans that reached it, and their count."""

    def mean_at(level: float) -> dict:
        rows = [r for r in (c.at(level) for c in curves) if r is not None]
        means = {k: (float(np.mean([r[k] for r in rows])) if rows else None) for k in SERIES}
        return {**means, "n": len(rows)}

    levels = {f"{level:.2f}": mean_at(level) for level in REPORT_LEVELS}
    curve_rows = [mean_at(float(level)) for level in CURVE_LEVELS]
    return {
        "levels": levels,
        "curve": {
            "true_coverage": CURVE_LEVELS.tolist(),
            **{k: [row[k] for row in curve_rows] for k in (*SERIES, "n")},
        },
        "per_plan": [
            {
                "plan": c.name,
                "steps": c.steps,
                "final_true_coverage": float(c.true_coverage[-1]),
                "final": c.at(float(c.true_coverage[-1])),
                "at": {f"{level:.2f}": c.at(level) for level in REPORT_LEVELS},
            }
            for c in curves
        ],
    }


def plot_summary(summary: dict, path: Path, title: str) -> None:
    """Paper-style curves: F1 (with / without prediction) and coverage, correct coverage vs true coverage."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = summary["curve"]
    x = np.array(curve["true_coverage"]) * 100

    def y(key: str) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in curve[key]], dtype=float)

    fig, (ax_f1, ax_cov) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    ax_f1.plot(x, y("f1"), label="observed + prediction")
    ax_f1.plot(x, y("f1_observed"), "--", label="observed only")
    ax_f1.plot(x, y("f1_ceiling"), ":", color="0.4", label="perfect prediction (ceiling)")
    for level in REPORT_LEVELS:
        ax_f1.axvline(level * 100, color="0.85", lw=0.8, zorder=0)
    ax_f1.set(xlabel="true coverage (%)", ylabel="F1", ylim=(0, 1.02), title="F1")
    ax_f1.legend(loc="lower right")
    ax_cov.plot(x, y("coverage") * 100, label="coverage (observed + prediction)")
    ax_cov.plot(x, y("correct_coverage") * 100, label="correct coverage")
    ax_cov.plot(x, x, ":", color="0.5", label="observed only")
    ax_cov.set(xlabel="true coverage (%)", ylabel="%", ylim=(0, 102), title="coverage")
    ax_cov.legend(loc="lower right")
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


_WORKER_PREDICTORS: dict[str, Predictor] = {}


def _evaluate_unit(
    predictor: Predictor | str,
    explorer_name: str,
    seed: int,
    thresholds: ThresholdConfig,
    sensor: SensorConfig,
    unit: tuple[int, PlanRaster],
) -> PlanCurve:
    """Plan ``k`` of an evaluation; a predictor reference is loaded once per process (a Ray worker's)."""
    k, raster = unit
    if isinstance(predictor, str):
        if predictor not in _WORKER_PREDICTORS:
            from edge_explorer.learn.loaders import load_predictor

            _WORKER_PREDICTORS[predictor] = load_predictor(predictor)
        predictor = _WORKER_PREDICTORS[predictor]
    if isinstance(predictor, PredictorRuntime) and predictor.calibration is not None:
        predictor = predictor.uncalibrated()  # the raw output, measured before and after the map (module docstring)
    thresholds = dataclasses.replace(thresholds, calibration=None)
    rng = np.random.default_rng([seed, k])
    return evaluate_plan(
        Scene.from_raster(raster), predictor, make_explorer(explorer_name), rng, thresholds, sensor=sensor
    )


def evaluate(
    plans_ref: str,
    predictor: Predictor | str,
    explorer_name: str = "random-goal",
    seed: int = 0,
    limit: int | None = None,
    thresholds: ThresholdConfig = DEFAULT_THRESHOLDS,
    sensor: SensorConfig = DEFAULT_SENSOR,
    ray: str | None = None,
) -> dict:
    """Fly and score every plan of ``plans_ref``; plan ``k`` uses the seed sequence (seed, k).

    ``predictor`` is a predictor or a reference for :func:`~edge_explorer.learn.loaders.load_predictor`; with ``ray``
    (``"auto"`` or an address) the plans are Ray tasks, each loading the predictor from its reference."""
    from edge_explorer.world.catalog import load_buildings

    rasters = load_buildings(plans_ref)[:limit]
    return evaluate_rasters(plans_ref, rasters, predictor, explorer_name, seed, thresholds, sensor, ray)


def evaluate_rasters(
    plans_ref: str,
    rasters: Sequence[PlanRaster],
    predictor: Predictor | str,
    explorer_name: str = "random-goal",
    seed: int = 0,
    thresholds: ThresholdConfig = DEFAULT_THRESHOLDS,
    sensor: SensorConfig = DEFAULT_SENSOR,
    ray: str | None = None,
) -> dict:
    """:func:`evaluate` on plans already loaded (``plans_ref`` names them in the report). The reliability of the
    calibrated probabilities is that of ``thresholds.calibration`` (the runtime's own, :func:`thresholds_of`)."""
    from tqdm import tqdm

    if ray is not None and not isinstance(predictor, str):
        raise ValueError("with ray, pass the predictor as a reference (a path) that every worker can load")
    explorer = make_explorer(explorer_name)
    t0 = time.perf_counter()
    unit = functools.partial(_evaluate_unit, predictor, explorer_name, seed, thresholds, sensor)
    finished = map_units(unit, list(enumerate(rasters)), ray=ray)
    by_plan = dict(tqdm(finished, total=len(rasters), desc="eval predictor", unit="plan"))
    curves = [by_plan[k] for k in range(len(rasters))]
    return {
        "plans": plans_ref,
        "n_plans": len(curves),
        "explorer": explorer.name,
        "seed": seed,
        "flight_limits": {"max_steps": EVAL_LIMITS.max_steps, "stall_steps": EVAL_LIMITS.stall_steps},
        "sensor_occupied_noise_prob": sensor.occupied_noise_prob,
        "thresholds": {"t_f_max": thresholds.t_f_max, "t_o": thresholds.t_o},
        "seconds": time.perf_counter() - t0,
        **summarize(curves),
        "reliability": reliability_report(curves, thresholds.calibration),
    }


def evaluate_cli(args: argparse.Namespace) -> int:
    """``edge-explorer eval predictor``: figures to --json, curves to --plot, a table on stdout."""
    import torch

    from edge_explorer.cli_support import write_json

    torch.set_num_threads(1)
    from edge_explorer.learn.loaders import load_predictor

    predictor = load_predictor(str(args.model))
    weights = args.model / CARD_FILE if args.model.is_dir() else args.model
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=args.occupied_noise)
    reference = str(args.model) if args.ray else predictor  # Ray workers load their own
    thresholds = thresholds_of(predictor)  # an exported model's card may carry calibrated ones (docs/design.md §5)
    if args.thresholds is not None:
        thresholds = dataclasses.replace(thresholds, t_f_max=args.thresholds[0], t_o=args.thresholds[1])
    report = evaluate(
        args.plans, reference, args.explorer, args.seed, args.limit, thresholds, sensor=sensor, ray=args.ray
    )
    report = {"model": str(args.model), "model_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(), **report}
    write_json(args.json, report)
    if args.plot:
        plot_summary(
            report, args.plot, f"{args.model.name} on {args.plans} ({report['n_plans']} plans, {report['explorer']})"
        )
    print(
        f"{report['n_plans']} plans, explorer {report['explorer']}: true coverage → F1 with prediction "
        "(observed only, perfect prediction), coverage, correct coverage, plans that reached it"
    )
    for level, row in report["levels"].items():
        if row["n"] == 0:
            print(f"  {float(level):4.0%}: no plan reached it")
            continue
        print(
            f"  {float(level):4.0%}: F1 {row['f1']:.3f} (observed {row['f1_observed']:.3f}, ceiling "
            f"{row['f1_ceiling']:.3f}), coverage {row['coverage']:.3f}, correct {row['correct_coverage']:.3f}, "
            f"n={row['n']}"
        )
    rel = report["reliability"]
    for name in ("raw", "calibrated"):
        if rel.get(name):
            r = rel[name]
            print(
                f"  reliability, {name} probabilities ({r['cells']} unobserved interior cells, {r['bins']} bins): "
                f"ECE {r['ece']:.4f}, MCE {r['mce']:.4f}, Brier {r['brier']:.4f}"
            )
    if args.reliability_plot and rel.get("raw"):
        counts = ProbabilityCounts.from_json(rel["counts"])
        calibration = thresholds.calibration
        curves = {"raw": counts.reliability(rel["bins"])}
        if calibration is not None:
            curves["calibrated"] = counts.reliability(rel["bins"], calibration)
        noise = f"sensor noise {args.occupied_noise:g}" if args.occupied_noise else "no sensor noise"
        args.reliability_plot.parent.mkdir(parents=True, exist_ok=True)
        plot_reliability(curves, args.reliability_plot, f"{args.model.name} on {args.plans}, {noise}")
    return 0
