"""Val curves of goal-PPO runs (issue #21, session 23): path at 95 % on the run's eval plans and the critic's
explained variance, against decisions, with the BC start as a line.

    python docs/policy/session23/plot_ppo.py out.png --bc 36.66 "no warm-up=runs/s23/ppo" "warm-up 4096=runs/s23/ppo_vw"

Each run folder is a ``train goal-ppo --out`` folder (``val_log.csv`` and SB3's TensorBoard events).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator  # noqa: E402


def explained_variance(run: Path) -> tuple[list[int], list[float]]:
    """(decisions, explained variance) of every PPO update in the run's TensorBoard events."""
    steps, values = [], []
    for folder in sorted(run.glob("MaskablePPO_*")):
        events = EventAccumulator(str(folder))
        events.Reload()
        for event in events.Scalars("train/explained_variance"):
            steps.append(event.step)
            values.append(event.value)
    return steps, values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("runs", nargs="+", help="label=run folder")
    parser.add_argument("--bc", type=float, help="the BC start's mean path on the same eval plans (m)")
    args = parser.parse_args()
    fig, (path_ax, ev_ax) = plt.subplots(1, 2, figsize=(11, 4))
    for item in args.runs:
        label, _, folder = item.partition("=")
        rows = list(csv.DictReader((Path(folder) / "val_log.csv").open()))
        path_ax.plot([int(r["decisions"]) for r in rows], [float(r["mean_path_m"]) for r in rows], "o-", label=label)
        ev_ax.plot(*explained_variance(Path(folder)), label=label, alpha=0.8)
    if args.bc is not None:
        path_ax.axhline(args.bc, color="grey", ls="--", label="BC start (shipped policy)")
    path_ax.set(xlabel="decisions", ylabel="mean path at 95 % (m), 10 val plans", title="deterministic policy on val")
    ev_ax.set(xlabel="decisions", ylabel="explained variance", title="critic")
    for ax in (path_ax, ev_ax):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"→ {args.out}")


if __name__ == "__main__":
    main()
