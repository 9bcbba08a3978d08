"""Calibrate training-run weights that were never exported, as ``train calibrate-predictor`` calibrates a card
(issue #17, session 21): same val flights (random-goal explorer, seed (0, k) for plan k, occupied noise 0.1), same
precision target and pair grid, but the fp32 torch model of a run's ``.safetensors`` and no card written.

It answers what the threshold-free F1 of session 20 cannot: at the precision the card requires of the thresholded
cells, how much coverage does each model's prediction add, each at the pair chosen for it.

    python docs/predictor/session21/calibrate_weights.py runs/s20/lev/wall2/checkpoint.safetensors --out cal_wall2.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path


def main() -> None:
    from edge_explorer.bench.explore import load_predictor
    from edge_explorer.learn.calibrate_predictor import collect_samples
    from edge_explorer.learn.predictor_data import DEFAULT_SENSOR
    from edge_explorer.predict.calibration import calibrate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights", type=Path, help="a training run's .safetensors")
    parser.add_argument("--plans", type=int, default=40, help="val plans to fly (the card's calibration: 40)")
    parser.add_argument("--target", type=float, default=0.95, help="precision of the thresholded cells")
    parser.add_argument("--out", type=Path, required=True, help="JSON: chosen pair, its precision and coverage added")
    args = parser.parse_args()
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=0.1)
    _, samples = collect_samples(load_predictor(str(args.weights)), args.plans, sensor=sensor)
    calibration = calibrate(samples, args.target)
    report = {"weights": str(args.weights), "plans": args.plans, **calibration.to_json()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    chosen = calibration.chosen
    print(f"{args.weights}: pair ({chosen.t_f_max:g}, {chosen.t_o:g}), meets {args.target:.0%}: {calibration.met_target}")
    for level in calibration.levels:
        print(f"  {level:4.0%}: precision {chosen.precision[level]}, coverage added +{chosen.coverage_added[level]:.4f}")


if __name__ == "__main__":
    main()
