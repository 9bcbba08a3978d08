"""Coverage against path on building C: the daemon's flights (15 Hz and 2 Hz depth) beside the benchmark's runs
and its variants (docs/runtime/README.md, session 33). Writes the figure and the mean curves it draws.

    python docs/runtime/session33/plot_c_curves.py runs/s30/acc/C runs/s33/depth/C2 docs/runtime/session33/c_curves
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

PATH_GRID_M = np.arange(0.0, 40.01, 0.5)
HERE = Path(__file__).parent


def _on_grid(path_m: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """Coverage at each grid path length (the last value reached by then); NaN past the run's end."""
    idx = np.searchsorted(path_m, PATH_GRID_M, side="right") - 1
    out = np.where(idx >= 0, coverage[np.clip(idx, 0, None)], np.nan)
    out[PATH_GRID_M > path_m[-1]] = np.nan
    return out


def _daemon(folder: Path) -> np.ndarray:
    rows = []
    for summary in sorted(folder.glob("*-run*/summary.json")):
        timeline = np.array([r for r in json.loads(summary.read_text())["timeline"] if r[1] is not None], float)
        rows.append(_on_grid(timeline[:, 3], timeline[:, 1]))
    return np.array(rows)


def _bench(variant: str) -> np.ndarray:
    curves = json.loads((HERE / f"C_{variant}.json").read_text())["curves"]
    return np.array([_on_grid(np.array(c["path_length_m"]), np.array(c["coverage"])) for c in curves])


def main() -> None:
    daemon15, daemon2, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    series = {
        "daemon, depth 15 Hz (session 30, 5 flights)": _daemon(daemon15),
        "daemon, depth 2 Hz (5 flights)": _daemon(daemon2),
        "bench (10 runs)": _bench("default"),
        "bench, sensor noise off": _bench("no-sensor-noise"),
        "bench, motion noise off": _bench("no-motion-noise"),
    }
    with warnings.catch_warnings():  # past the longest run a column is all NaN, and its mean is NaN: not drawn
        warnings.simplefilter("ignore", RuntimeWarning)
        means = {name: np.nanmean(rows, axis=0) for name, rows in series.items()}
    fig, ax = plt.subplots(figsize=(8, 5))
    for name, mean in means.items():
        ax.plot(PATH_GRID_M, mean, label=name, linestyle="-" if name.startswith("daemon") else "--")
    ax.axhline(0.95, color="grey", linewidth=0.8)
    ax.set(xlabel="path flown (m)", ylabel="coverage (mean over runs)", title="Building C, drl+pred: daemon vs bench")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=110)
    table = {name: np.round(mean, 4).tolist() for name, mean in means.items()}
    out.with_suffix(".json").write_text(json.dumps({"path_m": PATH_GRID_M.tolist(), "mean_coverage": table}) + "\n")
    for path in (3, 5, 10, 15, 20, 25, 30):
        i = int(np.argmin(abs(PATH_GRID_M - path)))
        print(f"{path:>3} m: " + "  ".join(f"{m[i]:.3f}" for m in means.values()))


if __name__ == "__main__":
    main()
