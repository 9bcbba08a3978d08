"""How far thresholding alone can take F1 with sensor noise (issue #17, session 19).

Flies the evaluation's flights (random-goal explorer, seed (0, k) for plan k, occupied noise as given) with the
shipped int8 predictor, keeps the map at the first scan reaching 80 / 95 / 98 % true coverage, and scores F1 of the
observed map plus the prediction thresholded with several (t_f_max, t_o) pairs, down to filling every unobserved cell
(0.5 / 0.5), beside the ceiling (every unobserved cell right). Labelling a cell never lowers F1 = TP / (TP + ½(N_M − T))
against leaving it UNKNOWN, so the filled map is about the best any pair can do with these probabilities.

    python docs/predictor/session19/f1_bound.py collect --split val --plans 100 --out bound_val.json
    python docs/predictor/session19/f1_bound.py plot bound_val.json bound_test.json --png bound.png
    python docs/predictor/session19/f1_bound.py paired base.json wall2.json  # B − A, per sample

``--model`` also takes a training run's ``best.safetensors`` (the torch model, fp32), so models that were never
exported compare like for like (session 20's levers); ``--levels`` picks the true-coverage levels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

PAIRS = ((0.35, 0.96), (0.35, 0.9), (0.35, 0.8), (0.35, 0.7), (0.35, 0.6), (0.45, 0.55), (0.4, 0.5), (0.5, 0.5))
LEVELS = (0.8, 0.95, 0.98)


def collect(split: str, plans: int, noise: float, model: Path, levels: tuple[float, ...] = LEVELS) -> dict:
    from edge_explorer.bench.explore import load_predictor
    from edge_explorer.learn.calibrate_predictor import collect_samples
    from edge_explorer.learn.predictor_flights import DEFAULT_SENSOR
    from edge_explorer.mapping.metrics import map_metrics
    from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map

    predictor = load_predictor(str(model))
    sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=noise)
    _, samples = collect_samples(predictor, plans, levels=levels, sensor=sensor, split=split)
    out: dict = {"split": split, "plans": plans, "noise": noise, "model": str(model), "levels": {}}
    for level in levels:
        at = [s for s in samples if s.level == level]
        observed = [map_metrics(s.observed, s.truth, s.interior).f1 for s in at]
        row = {
            "n": len(at),
            "ceiling": float(np.mean([map_metrics(s.observed, s.truth, s.interior, s.truth).f1 for s in at])),
            "observed": float(np.mean(observed)),
            "per_sample": {"observed": np.round(observed, 6).tolist()},
        }
        for t_f, t_o in PAIRS:
            config = ThresholdConfig(t_f, t_o)
            filled = [thresholded_map(s.probabilities, s.observed, s.observed_area_m2, config) for s in at]
            f1 = [map_metrics(s.observed, s.truth, s.interior, t).f1 for s, t in zip(at, filled, strict=True)]
            row[f"{t_f}/{t_o}"] = float(np.mean(f1))
            row["per_sample"][f"{t_f}/{t_o}"] = np.round(f1, 6).tolist()
        out["levels"][str(level)] = row
    return out


def paired(path_a: Path, path_b: Path) -> str:
    """B − A per level and pair (mean ± s.e. over samples) of two collects of the same flights: the explorer does not
    read the predictor, so sample k is the same map in both (checked on the observed map's F1)."""
    a, b = (json.loads(p.read_text())["levels"] for p in (path_a, path_b))
    lines = []
    for level in a:
        sa, sb = a[level]["per_sample"], b[level]["per_sample"]
        if sa["observed"] != sb["observed"]:
            raise SystemExit(f"level {level}: the two files are not the same flights; collect both with one command")
        for pair in (k for k in sa if k != "observed"):
            d = np.array(sb[pair]) - np.array(sa[pair])
            lines.append(
                f"{level} {pair}: {d.mean():+.4f} ± {d.std(ddof=1) / np.sqrt(len(d)):.4f} (B better on "
                f"{(d > 0).sum()}/{len(d)})"
            )
    return "\n".join(lines)


def plot(paths: list[Path], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(LEVELS), figsize=(12, 3.6), constrained_layout=True)
    labels = [f"{t_f}/{t_o}" for t_f, t_o in PAIRS]
    for ax, level in zip(axes, LEVELS, strict=True):
        for path in paths:
            doc = json.loads(path.read_text())
            row = doc["levels"][str(level)]
            line = ax.plot(range(len(labels)), [row[k] for k in labels], "o-", label=f"{doc['split']} ({doc['plans']})")
            ax.axhline(row["ceiling"], ls=":", color=line[0].get_color())
        if level == 0.98:
            ax.axhline(0.905, color="red", lw=0.8, label="#17 target 0.905")
        ax.set_xticks(range(len(labels)), labels, rotation=45, fontsize=7)
        ax.set(title=f"F1 at {level:.0%} true coverage, noisy", xlabel="t_f_max / t_o (dotted: ceiling)")
        ax.legend(fontsize=7)
    fig.savefig(png, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--split", default="val")
    c.add_argument("--plans", type=int, default=100)
    c.add_argument("--noise", type=float, default=0.1)
    c.add_argument("--model", type=Path, default=Path("models/predictor"))
    c.add_argument("--levels", type=float, nargs="+", default=list(LEVELS), help="true coverage levels")
    c.add_argument("--out", type=Path, required=True)
    d = sub.add_parser("paired", help="B − A of two collects of the same flights")
    d.add_argument("a", type=Path)
    d.add_argument("b", type=Path)
    p = sub.add_parser("plot")
    p.add_argument("json", type=Path, nargs="+")
    p.add_argument("--png", type=Path, required=True)
    args = parser.parse_args()
    if args.command == "collect":
        figures = collect(args.split, args.plans, args.noise, args.model, tuple(args.levels))
        args.out.write_text(json.dumps(figures, indent=1) + "\n")
    elif args.command == "paired":
        print(paired(args.a, args.b))
    else:
        plot(args.json, args.png)


if __name__ == "__main__":
    main()
