"""Held-out check of calibrated thresholds (issue #17): precision of the predicted-known cells and the coverage they
add, on the **test** split, for the shipped predictor and for any other exported model folder.

Run from the repository root::

    python scripts/heldout_precision.py models/predictor runs/pred_old --json docs/predictor/heldout_test.json

Each model is scored with its own card's thresholds, with the sensor noise of training (0.1) and without it, on
samples taken as ``train calibrate-predictor`` takes them (first scan at 50 / 80 / 95 % true coverage of the
random-goal flights of the first 100 test plans). Nothing is chosen here: the thresholds were chosen on val.
"""

import argparse
import dataclasses
import json
from pathlib import Path

from edge_explorer.learn.calibrate_predictor import collect_samples
from edge_explorer.learn.loaders import load_predictor
from edge_explorer.learn.predictor_flights import DEFAULT_SENSOR
from edge_explorer.predict.calibration import score_pair
from edge_explorer.predict.predictor import thresholds_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="exported model folders (card.json with thresholds)")
    parser.add_argument("--plans", type=int, default=100)
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args()
    report = {}
    for model in args.models:
        predictor = load_predictor(model)
        thresholds = thresholds_of(predictor)
        rows = {}
        for noise in (0.1, 0.0):
            sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=noise)
            _, samples = collect_samples(predictor, args.plans, sensor=sensor, split="test")
            rows[f"noise {noise}"] = score_pair(samples, thresholds).to_json()
        report[model] = rows
        for label, row in rows.items():
            precision, added = row["precision"], row["coverage_added"]
            cells = ", ".join(f"{lv}: {precision[lv]:.3f} / +{100 * added[lv]:.1f} pts" for lv in precision)
            print(f"{model} (t_f_max {thresholds.t_f_max}, t_o {thresholds.t_o}), {label}: {cells}")
    args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
