"""Side-by-side val curves of predictor runs trained from scratch on the same data and budget (issue #17 levers).

Run from the repository root, one ``LABEL=FOLDER`` per run (each folder holds ``val_log.csv``)::

    python docs/predictor/session19/plot_levers.py docs/predictor/session19/levers.png \\
        "shipped architecture (5 levels, 0.44 GMAC)=docs/predictor/session19/lever_base" \\
        "one more level (6 levels, 0.49 GMAC)=docs/predictor/session19/lever_deep6"
"""

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

BINS = (("val_f1_cov0.50", "50–80 %"), ("val_f1_cov0.80", "80–95 %"), ("val_f1_cov0.95", "≥ 95 %"))


def main(png: str, runs: list[str]) -> None:
    fig, axes = plt.subplots(1, len(BINS) + 1, figsize=(15, 3.6), constrained_layout=True)
    for run in runs:
        label, folder = run.split("=", 1)
        with open(Path(folder) / "val_log.csv") as fh:
            rows = list(csv.DictReader(fh))
        samples = [int(r["samples"]) / 1000 for r in rows]
        for ax, (key, title) in zip(axes, BINS, strict=False):
            ax.plot(samples, [float(r[key]) for r in rows], "o-", label=label)
            ax.set(title=f"val F1, true coverage {title}", xlabel="samples seen (thousands)")
        axes[-1].plot(samples, [float(r["val_loss"]) for r in rows], "o-", label=label)
    axes[-1].set(title="val loss (weighted BCE)", xlabel="samples seen (thousands)", yscale="log")
    axes[0].legend(fontsize=7)
    fig.savefig(png, dpi=120)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
