"""Calibrate training-run weights that were never exported, as ``train calibrate-predictor`` calibrates a card
(issue #17, session 21): same val flights (random-goal explorer, seed (0, k) for plan k, occupied noise 0.1), same
precision target and pair grid, but the fp32 torch model of a run's ``.safetensors`` and no card written.

It answers what the threshold-free F1 of session 20 cannot: at the precision the card requires of the thresholded
cells, how much coverage does each model's prediction add, each at the pair chosen for it.

    python docs/predictor/session21/calibrate_weights.py runs/s20/lev/wall2/checkpoint.safetensors --out cal_wall2.json
    python docs/predictor/session21/calibrate_weights.py --show cal_base.json cal_wall2.json --png cal.png
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path


def main() -> None:
    from edge_explorer.bench.explore import load_predictor
    from edge_explorer.learn.calibrate_predictor import collect_samples
    from edge_explorer.learn.predictor_flights import DEFAULT_SENSOR
    from edge_explorer.predict.calibration import calibrate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights", type=Path, nargs="?", help="a training run's .safetensors")
    parser.add_argument("--show", type=Path, nargs="+", help="print the summaries of finished JSONs and exit")
    parser.add_argument("--plans", type=int, default=40, help="val plans to fly (the card's calibration: 40)")
    parser.add_argument("--target", type=float, default=0.95, help="precision of the thresholded cells")
    parser.add_argument("--png", type=Path, help="with --show: the precision / coverage-added trade-off per level")
    parser.add_argument("--out", type=Path, help="JSON: the chosen pair, its precision and coverage added, the table")
    args = parser.parse_args()
    if args.show:
        reports = [json.loads(path.read_text()) for path in args.show]
        print("\n".join(summary(report) for report in reports))
        if args.png:
            plot(reports, args.png)
        return
    if args.weights is None or args.out is None:
        parser.error("give the weights and --out (or --show JSON ...)")
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=0.1)
    _, samples = collect_samples(load_predictor(str(args.weights)), args.plans, sensor=sensor)
    calibration = calibrate(samples, args.target)
    report = {"weights": str(args.weights), "plans": args.plans, **calibration.to_json()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(summary(report))


def plot(reports: list[dict], png: Path) -> None:
    """Per level, each model's best coverage added at a given worst-level precision: the trade-off its thresholds
    offer, every pair of the calibration grid, upper envelope only."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = list(reports[0]["chosen"]["precision"])
    fig, axes = plt.subplots(1, len(levels), figsize=(4.2 * len(levels), 3.6), sharey=False)
    for ax, level in zip(axes, levels, strict=True):
        for report in reports:
            rows = [r for r in report["table"] if None not in r["precision"].values()]
            points = sorted((min(r["precision"].values()), r["coverage_added"][level]) for r in rows)
            envelope, best = [], -1.0
            for precision, added in reversed(points):
                if added > best:
                    envelope.append((precision, added))
                    best = added
            x, y = zip(*envelope, strict=True)
            ax.plot(x, y, label=Path(report["weights"]).parent.name)
        ax.axvline(0.95, color="grey", lw=0.8, ls="--")
        ax.set(xlim=(0.85, 1.0), title=f"{float(level):.0%} true coverage", xlabel="worst-level precision")
        ax.set_ylabel("coverage added")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)


def summary(report: dict) -> str:
    """One line per level: the chosen pair's precision and the coverage its thresholded prediction adds."""
    chosen = report["chosen"]
    lines = [f"{report['weights']}: pair ({chosen['t_f_max']:g}, {chosen['t_o']:g}), meets: {report['met_target']}"]
    for level, precision in chosen["precision"].items():
        lines.append(f"  {float(level):4.0%}: precision {precision:.4f}, added +{chosen['coverage_added'][level]:.4f}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
