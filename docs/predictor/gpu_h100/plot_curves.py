"""Training curves of the shipped predictor's two H100 stretches (issue #17): val F1 per coverage bin against
samples seen and wall time.

Run from the repository root: ``python docs/predictor/gpu_h100/plot_curves.py``; reads ``stretch3/`` and
``stretch4/`` (the CSV logs the runs wrote), writes ``curves.png`` beside this file.
"""

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).parent
BINS = (("val_f1_cov0.50", "50–80 %"), ("val_f1_cov0.80", "80–95 %"), ("val_f1_cov0.95", "≥ 95 %"))
STRETCHES = (
    ("stretch3", "stretch 3: from scratch"),
    ("stretch4", "stretch 4: fine-tune of 3 (shipped: best val, step 3,500)"),
)


def rows(path: Path) -> list[dict]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def wall_at(train_log: list[dict], step: int) -> float:
    """Training wall time (s) at ``step``, from the nearest logged step at or before it."""
    logged = [r for r in train_log if int(r["step"]) <= step]
    return float(logged[-1]["wall_s"]) if logged else 0.0


def main() -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    offset_samples, offset_wall = 0, 0.0
    for folder, label in STRETCHES:
        val, train = rows(HERE / folder / "val_log.csv"), rows(HERE / folder / "train_log.csv")
        samples = [offset_samples + int(r["samples"]) for r in val]
        wall = [offset_wall + wall_at(train, int(r["step"])) for r in val]
        for (key, bin_label), colour in zip(BINS, ("tab:blue", "tab:orange", "tab:green"), strict=True):
            f1 = [float(r[key]) for r in val]
            style = "-" if folder == "stretch3" else "--"
            axes[0].plot(samples, f1, style, color=colour, marker="o", ms=3, label=f"{bin_label}, {label}")
            axes[1].plot(wall, f1, style, color=colour, marker="o", ms=3)
        offset_samples, offset_wall = samples[-1], wall[-1]
    axes[0].set_xlabel("training samples seen")
    axes[1].set_xlabel("training wall time on the H100 (s; validation excluded)")
    for ax in axes:
        ax.set_ylabel("val F1 (observed + thresholded prediction)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Map predictor on a lent H100: val F1 per true-coverage bin (512 val samples, default thresholds)")
    fig.tight_layout()
    fig.savefig(HERE / "curves.png", dpi=120)


if __name__ == "__main__":
    main()
