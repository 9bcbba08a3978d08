"""Training curves of predictor stretches (issue #17): val F1 per coverage bin against samples seen and wall time.

Run from the repository root, one ``LABEL=PREFIX`` per stretch, oldest first (each continues the previous one's
samples and wall time); a stretch's logs are ``PREFIXval_log.csv`` and ``PREFIXtrain_log.csv``::

    python docs/predictor/plot_curves.py docs/predictor/gpu_h100/curves.png H100 \\
        "stretch 3: from scratch=docs/predictor/gpu_h100/stretch3/" \\
        "stretch 4: fine-tune of 3 (best val, step 3,500)=docs/predictor/gpu_h100/stretch4/" \\
        "stretch 5: fine-tune of 4 on 8,900 plans=docs/predictor/gpu_h100/stretch5/" \\
        "stretch 6: fine-tune of 5 on 10,500 plans (shipped: step 7,700)=docs/predictor/gpu_h100/stretch6/" \\
        "stretch 7: fine-tune of 6 on 16,350 plans (not shipped)=docs/predictor/gpu_h100/stretch7/"
    python docs/predictor/plot_curves.py docs/predictor/gpu_h200/curves.png H200 \\
        "stretch 1=docs/predictor/gpu_h200/" "stretch 2: fine-tune of 1 (int8 gate failed)=docs/predictor/gpu_h200/ft_"
"""

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

BINS = (("val_f1_cov0.50", "50–80 %"), ("val_f1_cov0.80", "80–95 %"), ("val_f1_cov0.95", "≥ 95 %"))


def rows(path: str) -> list[dict]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def wall_at(train_log: list[dict], step: int) -> float:
    """Training wall time (s) at ``step``, from the nearest logged step at or before it."""
    logged = [r for r in train_log if int(r["step"]) <= step]
    return float(logged[-1]["wall_s"]) if logged else 0.0


def main(out: Path, hardware: str, stretches: list[str]) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    offset_samples, offset_wall = 0, 0.0
    captions: list[str] = []
    for k, stretch in enumerate(stretches):
        label, prefix = stretch.rsplit("=", 1)
        val, train = rows(f"{prefix}val_log.csv"), rows(f"{prefix}train_log.csv")
        samples = [offset_samples + int(r["samples"]) for r in val]
        wall = [offset_wall + wall_at(train, int(r["step"])) for r in val]
        for (key, bin_label), colour in zip(BINS, ("tab:blue", "tab:orange", "tab:green"), strict=True):
            f1 = [float(r[key]) for r in val]
            style = "-" if k % 2 == 0 else "--"
            axes[0].plot(samples, f1, style, color=colour, marker="o", ms=3, label=bin_label if k == 0 else None)
            axes[1].plot(wall, f1, style, color=colour, marker="o", ms=3)
        # each stretch starts at a dotted line, named in the figure's caption (one line per stretch, below)
        for ax, x in ((axes[0], offset_samples), (axes[1], offset_wall)):
            ax.axvline(x, color="grey", ls=":", lw=0.8)
            ax.text(x, 0.02, f" {k + 1}", transform=ax.get_xaxis_transform(), fontsize=8, color="grey")
        captions.append(f"{k + 1} = {label}")
        offset_samples, offset_wall = samples[-1], wall[-1]
    axes[0].set_xlabel("training samples seen")
    axes[1].set_xlabel("training wall time (s; validation excluded)")
    for ax in axes:
        ax.set_ylabel("val F1 (observed + thresholded prediction)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Map predictor on the {hardware}: val F1 per true-coverage bin (512 val samples, default thresholds)")
    fig.text(0.01, 0.01, "stretches: " + "; ".join(captions), fontsize=8, wrap=True)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(out, dpi=120)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], sys.argv[3:])
