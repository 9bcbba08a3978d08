"""Training curves of the GPU stretches (issue #17): val F1 per coverage bin against samples seen and wall time.

Run from the repository root: ``python docs/predictor/gpu_h200/plot_curves.py``; reads the CSV logs beside it,
writes ``curves.png`` beside it.
"""

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).parent
BINS = (("val_f1_cov0.50", "50–80 %"), ("val_f1_cov0.80", "80–95 %"), ("val_f1_cov0.95", "≥ 95 %"))


def rows(name: str) -> list[dict]:
    with open(HERE / name) as fh:
        return list(csv.DictReader(fh))


def wall_at(train_log: list[dict], step: int) -> float:
    """Training wall time (s) at ``step``, from the nearest logged step at or before it."""
    logged = [r for r in train_log if int(r["step"]) <= step]
    return float(logged[-1]["wall_s"]) if logged else 0.0


def main() -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    stretches = (
        ("", "stretch 1 (candidate, docs/predictor/gpu_h200)"),
        ("ft_", "stretch 2: fine-tune of 1 (int8 gate failed)"),
    )
    offset_samples, offset_wall = 0, 0.0
    for prefix, label in stretches:
        val, train = rows(f"{prefix}val_log.csv"), rows(f"{prefix}train_log.csv")
        samples = [offset_samples + int(r["samples"]) for r in val]
        wall = [offset_wall + wall_at(train, int(r["step"])) for r in val]
        for (key, bin_label), colour in zip(BINS, ("tab:blue", "tab:orange", "tab:green"), strict=True):
            f1 = [float(r[key]) for r in val]
            style = "-" if not prefix else "--"
            axes[0].plot(samples, f1, style, color=colour, marker="o", ms=3, label=f"{bin_label}, {label}")
            axes[1].plot(wall, f1, style, color=colour, marker="o", ms=3)
        offset_samples, offset_wall = samples[-1], wall[-1]
    axes[0].set_xlabel("training samples seen")
    axes[1].set_xlabel("training wall time on the H200 (s; validation excluded)")
    for ax in axes:
        ax.set_ylabel("val F1 (observed + thresholded prediction)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Map predictor on a lent H200: val F1 per true-coverage bin (512 val samples, default thresholds)")
    fig.tight_layout()
    fig.savefig(HERE / "curves.png", dpi=120)


if __name__ == "__main__":
    main()
