"""Summing up the exploration benchmark's run records: Table I, the paired differences, the failures and Fig. 5.

:mod:`edge_explorer.bench.explore` flies the runs and returns one record per run (its spec, how it ended, the
per-step curves); everything here only reads those records, so a summary can be redrawn from stored records (the
``--out-dir`` JSONs or a ``--json`` report) without flying anything again.

Per building and method (:func:`summarize`): the path length when coverage first reaches 95 % (min / max / avg /
std over the runs that reach it: Table I), the same for correct coverage, how many runs reach each, the success
rate (95 % coverage without a collision), steps and collisions; between methods, the paired per-building difference
of that path length (:func:`paired_differences`); the runs that missed the goal or collided, with why
(:func:`failures`); and the mean coverage curves against path length (:func:`mean_curves`, :func:`plot_curves`).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

CURVE_STEP_M = 0.5  # path-length spacing of the mean curves
_TITLE_CHARS_PER_INCH = 10  # the figure title wraps at this many characters per inch of width: one line outran a panel


# ---- statistics -------------------------------------------------------------------------------------------------
def _stats(values: Sequence[float]) -> dict[str, float | None]:
    if len(values) == 0:
        return {"min": None, "max": None, "avg": None, "std": None}
    a = np.asarray(values, dtype=np.float64)
    return {"min": float(a.min()), "max": float(a.max()), "avg": float(a.mean()), "std": float(a.std())}


# The paths every table reports (the brief: a user needs a correct map, so correct coverage counts): the record's
# own first crossings of the run's goal (95 %), and the path at 90 % correct coverage read from its curves.
METRICS: dict[str, str] = {
    "path_at_coverage_m": "path at 95 % coverage",
    "path_at_correct_90_m": "path at 90 % correct coverage",
    "path_at_correct_coverage_m": "path at 95 % correct coverage",
}
CORRECT_90 = 0.90


def path_at(record: dict[str, Any], metric: str) -> float | None:
    """The path (m) at which ``record`` first reached ``metric`` (a key of :data:`METRICS`), ``None`` if never."""
    if metric != "path_at_correct_90_m":
        return record[metric]
    correct, path = record["curves"]["correct_coverage"], record["curves"]["path_length_m"]
    return next((float(p) for c, p in zip(correct, path, strict=True) if c >= CORRECT_90), None)


# Path budgets (m) at which the correctly mapped area is reported, as MapEx does: a real vehicle flies 10–20 minutes.
BUDGETS_M: tuple[float, ...] = (100.0, 200.0, 400.0, 800.0)


def correct_area_at_m2(record: dict[str, Any], budget_m: float) -> float | None:
    """The correctly mapped area (m²: correct coverage × N_M) when ``record``'s path first reaches ``budget_m``; a
    run that ended before it keeps its final map. ``None`` for records without the N_M area (older records)."""
    if "n_m_m2" not in record:
        return None
    correct, path = record["curves"]["correct_coverage"], record["curves"]["path_length_m"]
    within = [c for c, p in zip(correct, path, strict=True) if p <= budget_m]
    return float(record["n_m_m2"] * (within[-1] if within else correct[0]))


def _group_summary(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    at_coverage = [r["path_at_coverage_m"] for r in records if r["path_at_coverage_m"] is not None]
    at_correct = [r["path_at_correct_coverage_m"] for r in records if r["path_at_correct_coverage_m"] is not None]
    at_correct_90 = [p for r in records if (p := path_at(r, "path_at_correct_90_m")) is not None]
    success = [r for r in records if r["path_at_coverage_m"] is not None and r["collisions"] == 0]
    return {
        "runs": len(records),
        "path_at_coverage_m": _stats(at_coverage),
        "reached_coverage": len(at_coverage),
        "path_at_correct_90_m": _stats(at_correct_90),
        "reached_correct_90": len(at_correct_90),
        "path_at_correct_coverage_m": _stats(at_correct),
        "reached_correct_coverage": len(at_correct),
        "success_rate": len(success) / len(records),
        "collisions": int(sum(r["collisions"] for r in records)),
        "runs_with_collision": sum(1 for r in records if r["collisions"] > 0),
        "steps": _stats([r["steps"] for r in records]),
        "final_coverage": _stats([r["final_coverage"] for r in records]),
        "final_correct_coverage": _stats([r["final_correct_coverage"] for r in records]),
        "endings": {e: sum(1 for r in records if r["ending"] == e) for e in ("goal", "explored", "step_cap")},
        "correct_area_at_budget_m2": {
            f"{b:g}": _stats([a for r in records if (a := correct_area_at_m2(r, b)) is not None]) for b in BUDGETS_M
        },
        "planner_ms_per_step": 1e3 * sum(r["planner_s"] for r in records) / max(sum(r["steps"] for r in records), 1),
        "wall_s": _stats([r["wall_s"] for r in records if "wall_s" in r]),
    }


def summarize(records: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """``{"plans": {plan: {method: summary}}, "all": {method: summary over every run}}``."""
    plans: dict[str, dict[str, Any]] = {}
    for plan in dict.fromkeys(r["spec"]["plan"] for r in records):
        plans[plan] = {
            m: _group_summary([r for r in records if r["spec"]["plan"] == plan and r["spec"]["method"] == m])
            for m in methods
        }
    overall = {m: _group_summary([r for r in records if r["spec"]["method"] == m]) for m in methods}
    return {"plans": plans, "all": overall}


def paired_differences(
    records: Sequence[dict[str, Any]], methods: Sequence[str], metric: str = "path_at_coverage_m"
) -> list[dict[str, Any]]:
    """For every pair of methods (a listed before b): b − a of the per-building average path at ``metric`` (a key
    of :data:`METRICS`), over the buildings where both reached it — paired mean, its standard error, median, and on
    how many buildings b was shorter. Pairing by building removes most of the spread between buildings, which
    dwarfs the difference between methods (on the test split the path to 95 % ranges from about 15 to 130 m)."""
    average: dict[str, dict[str, float]] = {m: {} for m in methods}
    for m in methods:
        paths: dict[str, list[float]] = {}
        for r in records:
            if r["spec"]["method"] == m and (p := path_at(r, metric)) is not None:
                paths.setdefault(r["spec"]["plan"], []).append(p)
        average[m] = {plan: float(np.mean(v)) for plan, v in paths.items()}
    out = []
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            d = np.array([average[b][plan] - average[a][plan] for plan in average[a] if plan in average[b]])
            n = len(d)
            out.append(
                {
                    "metric": metric,
                    "a": a,
                    "b": b,
                    "buildings": n,
                    "mean_m": float(d.mean()) if n else None,
                    "stderr_m": float(d.std(ddof=1) / math.sqrt(n)) if n > 1 else None,
                    "median_m": float(np.median(d)) if n else None,
                    "b_shorter": int((d < 0).sum()),
                }
            )
    return out


def markdown_paired(paired: Sequence[dict[str, Any]]) -> str:
    """The paired differences as a Markdown table (empty when there is nothing to compare)."""
    rows = [p for p in paired if p["buildings"] > 0]
    if not rows:
        return ""
    lines = [
        f"| paired difference, {METRICS[rows[0].get('metric', 'path_at_coverage_m')]} | mean ± s.e. (m) | median (m) "
        "| buildings | b shorter on |",
        "| --- | --- | --- | --- | --- |",
    ]
    for p in rows:
        stderr = "–" if p["stderr_m"] is None else f"{p['stderr_m']:.1f}"
        lines.append(
            f"| {p['b']} − {p['a']} | {p['mean_m']:+.1f} ± {stderr} | {p['median_m']:+.1f} | {p['buildings']} | "
            f"{p['b_shorter']} |"
        )
    return "\n".join(lines) + "\n"


def failures(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Runs that did not reach the coverage goal or collided, with how they ended."""
    return [
        {
            "method": r["spec"]["method"],
            "plan": r["spec"]["plan"],
            "run": r["spec"]["run"],
            "ending": r["ending"],
            "why": r.get("why", {}).get("text"),
            "final_coverage": r["final_coverage"],
            "collisions": r["collisions"],
            "steps": r["steps"],
        }
        for r in records
        if r["path_at_coverage_m"] is None or r["collisions"] > 0
    ]


def markdown_failures(failed: Sequence[dict[str, Any]], limit: int = 30) -> str:
    """The runs that missed the goal or collided, each with why it ended (the first ``limit``)."""
    if not failed:
        return ""
    lines = ["", f"Runs without 95 % coverage or with a collision ({len(failed)}):", ""]
    for f in failed[:limit]:
        crash = f", {f['collisions']} collision(s)" if f["collisions"] else ""
        lines.append(f"- {f['method']} on {f['plan']} run {f['run']}: {f['why'] or f['ending']}{crash}")
    if len(failed) > limit:
        lines.append(f"- … and {len(failed) - limit} more (see the JSON)")
    return "\n".join(lines) + "\n"


def _fmt_stats(s: dict[str, float | None]) -> str:
    if s["avg"] is None:
        return "–"
    return f"{s['min']:.1f} / {s['max']:.1f} / {s['avg']:.1f} / {s['std']:.1f}"


def markdown_table(summary: dict[str, Any], methods: Sequence[str], per_plan: bool = True) -> str:
    """Table I: per building (and over all runs) and method, path length at 95 % coverage and at 90 % / 95 % correct
    coverage; with the planner's time per step and each run's wall time (whole floors must stay cheap to plan)."""
    lines = [
        "| building | method | path at 95 % coverage (m) min / max / avg / std | reached | "
        "path at 90 % correct coverage (m) min / max / avg / std | reached | "
        "path at 95 % correct coverage (m) min / max / avg / std | reached | success | collisions | steps avg | "
        "planning (ms / step) | wall (s / run) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    groups = [*summary["plans"].items()] if per_plan else []
    if len(summary["plans"]) > 1 or not per_plan:
        groups.append((f"all ({len(summary['plans'])} plans)", summary["all"]))
    for plan, by_method in groups:
        for m in methods:
            s = by_method[m]
            wall = s["wall_s"]["avg"]
            lines.append(
                f"| {plan} | {m} | {_fmt_stats(s['path_at_coverage_m'])} | {s['reached_coverage']}/{s['runs']} | "
                f"{_fmt_stats(s['path_at_correct_90_m'])} | {s['reached_correct_90']}/{s['runs']} | "
                f"{_fmt_stats(s['path_at_correct_coverage_m'])} | {s['reached_correct_coverage']}/{s['runs']} | "
                f"{100 * s['success_rate']:.0f} % | {s['collisions']} | {s['steps']['avg']:.0f} | "
                f"{s['planner_ms_per_step']:.1f} | {'–' if wall is None else f'{wall:.0f}'} |"
            )
    return "\n".join(lines) + "\n"


def markdown_budgets(summary: dict[str, Any], methods: Sequence[str]) -> str:
    """Correctly mapped area (m², mean over every run) at each path budget, and its ratio to the first method's."""
    overall = summary["all"]
    keys = [f"{b:g}" for b in BUDGETS_M]
    if any(overall[m]["correct_area_at_budget_m2"][k]["avg"] is None for m in methods for k in keys):
        return ""
    head = " | ".join(f"at {k} m" for k in keys)
    lines = [f"| correctly mapped area (m²), mean | {head} |", "| --- |" + " --- |" * len(keys)]
    reference = overall[methods[0]]["correct_area_at_budget_m2"]
    for m in methods:
        areas = overall[m]["correct_area_at_budget_m2"]
        cells = []
        for k in keys:
            ratio = areas[k]["avg"] / reference[k]["avg"] if reference[k]["avg"] else float("nan")
            cells.append(f"{areas[k]['avg']:.0f} ({ratio:.2f} ×)")
        lines.append(f"| {m} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


# ---- curves and the figure ---------------------------------------------------------------------------------------
def mean_curves(records: Sequence[dict[str, Any]], step_m: float = CURVE_STEP_M) -> dict[str, Any]:
    """Coverage and correct coverage against path length, as mean and std over ``records``.

    Each run's curve is sampled every ``step_m`` metres of path (the value after the last step within that path
    length) and held at its final value after the run ended, so runs of different lengths average fairly.
    """
    longest = max(r["curves"]["path_length_m"][-1] for r in records)
    grid = np.arange(0.0, longest + step_m, step_m)
    out: dict[str, Any] = {"path_m": np.round(grid, 3).tolist()}
    for key in ("coverage", "correct_coverage"):
        sampled = []
        for r in records:
            path = np.asarray(r["curves"]["path_length_m"])
            values = np.asarray(r["curves"][key])
            sampled.append(values[np.searchsorted(path, grid, side="right") - 1])
        a = np.asarray(sampled)
        out[key] = {"mean": np.round(a.mean(axis=0), 5).tolist(), "std": np.round(a.std(axis=0), 5).tolist()}
    return out


def figure_panels(records: Sequence[dict[str, Any]], methods: Sequence[str], max_panels: int = 6) -> dict[str, Any]:
    """Mean curves per panel and method: one panel per building, or one for all of them if there are more than
    ``max_panels`` buildings (the test split)."""
    plans = list(dict.fromkeys(r["spec"]["plan"] for r in records))
    if len(plans) <= max_panels:
        panels = {p: [r for r in records if r["spec"]["plan"] == p] for p in plans}
    else:
        panels = {f"all {len(plans)} plans": list(records)}
    return {
        title: {m: mean_curves([r for r in group if r["spec"]["method"] == m]) for m in methods}
        for title, group in panels.items()
    }


def plot_curves(panels: dict[str, Any], path: Path, goal: float, title: str) -> None:
    """Fig. 5: mean coverage (solid) and correct coverage (dashed) against path length with ±1 std bands."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 4.2 * rows), squeeze=False)
    for ax, (panel, by_method) in zip(axes.ravel(), panels.items(), strict=False):
        for k, (method, curves) in enumerate(by_method.items()):
            color = f"C{k}"
            x = np.asarray(curves["path_m"])
            for key, style in (("coverage", "-"), ("correct_coverage", "--")):
                mean = np.asarray(curves[key]["mean"])
                std = np.asarray(curves[key]["std"])
                label = method if key == "coverage" else f"{method} (correct)"
                ax.plot(x, mean, style, color=color, lw=1.6 if key == "coverage" else 1.0, label=label)
                if key == "coverage":
                    ax.fill_between(x, np.clip(mean - std, 0, 1), np.clip(mean + std, 0, 1), color=color, alpha=0.2)
        ax.axhline(goal, color="0.4", lw=0.8, ls=":")
        ax.set_title(panel)
        ax.set_xlabel("path length [m]")
        ax.set_ylabel("coverage")
        ax.set_ylim(0, 1.01)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.suptitle(textwrap.fill(title, width=int(_TITLE_CHARS_PER_INCH * fig.get_figwidth())))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---- the oracle's yardstick (edge_explorer.bench.oracle) ---------------------------------------------------------
def oracle_ratios(
    summary: dict[str, Any], methods: Sequence[str], oracle_m: dict[str, float], metric: str = "path_at_coverage_m"
) -> dict[str, dict[str, Any]]:
    """Per method: its average path at ``metric`` over the oracle's path, per building and their mean over the
    buildings where both have one (paired by building, so big buildings do not outweigh small ones)."""
    out = {}
    for m in methods:
        per_plan = {
            plan: by_method[m][metric]["avg"] / oracle_m[plan]
            for plan, by_method in summary["plans"].items()
            if plan in oracle_m and oracle_m[plan] > 0 and by_method[m][metric]["avg"] is not None
        }
        mean = float(np.mean(list(per_plan.values()))) if per_plan else None
        out[m] = {"plans": per_plan, "mean": mean, "buildings": len(per_plan)}
    return out


def markdown_oracle(summary: dict[str, Any], methods: Sequence[str], oracle_m: dict[str, float]) -> str:
    """Table: per building the oracle's path and each method's average path at 95 % coverage with its ratio to the
    oracle; last row the mean ratio (paired by building)."""
    ratios = oracle_ratios(summary, methods, oracle_m)
    lines = [
        "| building | oracle (m) | " + " | ".join(f"{m} (m, ×oracle)" for m in methods) + " |",
        "| --- | --- | " + " | ".join("---" for _ in methods) + " |",
    ]
    for plan, by_method in summary["plans"].items():
        if plan not in oracle_m:
            continue
        cells = []
        for m in methods:
            avg, ratio = by_method[m]["path_at_coverage_m"]["avg"], ratios[m]["plans"].get(plan)
            cells.append("–" if avg is None or ratio is None else f"{avg:.1f} (×{ratio:.2f})")
        lines.append(f"| {plan} | {oracle_m[plan]:.1f} | " + " | ".join(cells) + " |")
    means = ["–" if ratios[m]["mean"] is None else f"×{ratios[m]['mean']:.2f}" for m in methods]
    shown = sum(plan in oracle_m for plan in summary["plans"])
    lines.append(f"| mean ratio ({shown} plans) | 1 | " + " | ".join(means) + " |")
    return "\n".join(lines) + "\n"
