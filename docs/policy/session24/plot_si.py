"""Per-plan path at 95 % of the self-imitated policy against the shipped one on three sets of val plans (session 24).

    python docs/policy/session24/plot_si.py docs/policy/session24/si_paired.png \\
        "val 40–135=docs/policy/session24/s24_si_last.json:docs/policy/session23/s23_drl_base.json" \\
        "val 136–231=docs/policy/session24/s24_si_last_b.json:docs/policy/session24/s24_drl_base_b.json" \\
        "val 232–327=docs/policy/session24/s24_si_last_c.json:docs/policy/session24/s24_drl_base_c.json"
"""

import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def paths(path: str) -> dict[str, float]:
    return {r[0]: r[1] for r in json.load(open(path))["runs"] if r[1] is not None}


def main() -> None:
    out, sets = sys.argv[1], sys.argv[2:]
    fig, axes = plt.subplots(1, len(sets), figsize=(5.5 * len(sets), 5), squeeze=False)
    for ax, spec in zip(axes[0], sets, strict=True):
        label, files = spec.split("=", 1)
        new, base = (paths(f) for f in files.split(":"))
        plans = sorted(set(new) & set(base))
        x, y = np.array([base[p] for p in plans]), np.array([new[p] for p in plans])
        d = y - x
        ax.scatter(x, y, s=12)
        lim = [min(x.min(), y.min()) - 1, max(x.max(), y.max()) + 1]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set(xlim=lim, ylim=lim, xlabel="shipped policy: path at 95 % (m)", ylabel="self-imitated: path at 95 % (m)")
        ax.set_title(f"{label}: {d.mean():+.2f} ± {d.std(ddof=1) / np.sqrt(len(d)):.2f} m over {len(d)} plans")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
