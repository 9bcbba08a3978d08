"""Summing up ``bench explore --stop map`` runs: how often the map stop rule stopped too early, and what it saved.

A run flown with ``--stop map`` (:func:`~edge_explorer.sim.runs.run_episode`) ends when the maps' own estimate of
the area still unverified falls below a threshold (:mod:`edge_explorer.predict.verification`), when the planner has
nothing left, or at the step cap — never by the truth. Against the truth (issue #56):

* **false stops**: runs whose correct coverage at the stop is below 90 % (:data:`~edge_explorer.sim.runs.
  FALSE_STOP_CORRECT`) — whatever ended them, since that is where the flight would have declared itself done;
* **path at the stop vs the reference's own end**: per building, the method's average path at its stop minus the
  average path of ``frontier`` (Nearest Frontier, no predictor) at its own end in the same run set — paired by
  building, as :func:`~edge_explorer.bench.summary.paired_differences` pairs, since buildings differ far more than
  methods. Nearest Frontier with the map rule ends when no reachable unknown space is left: its ordinary end.

Reads records only, like :mod:`edge_explorer.bench.summary`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from edge_explorer.bench.summary import _stats
from edge_explorer.sim.runs import FALSE_STOP_CORRECT

REFERENCE = "frontier"


def _correct_at_stop(record: dict[str, Any]) -> float:
    return float(
        record["correct_coverage_at_stop"] if "correct_coverage_at_stop" in record else record["final_correct_coverage"]
    )


def _path_at_stop(record: dict[str, Any]) -> float:
    return float(record["path_at_stop_m"] if "path_at_stop_m" in record else record["path_length_m"])


def _per_building(records: Sequence[dict[str, Any]], method: str) -> dict[str, float]:
    paths: dict[str, list[float]] = {}
    for r in records:
        if r["spec"]["method"] == method:
            paths.setdefault(r["spec"]["plan"], []).append(_path_at_stop(r))
    return {plan: float(np.mean(v)) for plan, v in paths.items()}


def stop_summary(
    records: Sequence[dict[str, Any]], methods: Sequence[str], reference: str = REFERENCE
) -> dict[str, dict[str, Any]]:
    """Per method: endings, false stops (count and rate), correct coverage and path at the stop, and the paired
    per-building difference of path at the stop to ``reference``'s own end (None when ``reference`` did not fly)."""
    ref = _per_building(records, reference) if reference in methods else None
    out = {}
    for m in methods:
        group = [r for r in records if r["spec"]["method"] == m]
        false = [r for r in group if _correct_at_stop(r) < FALSE_STOP_CORRECT]
        entry: dict[str, Any] = {
            "runs": len(group),
            "endings": {e: sum(1 for r in group if r["ending"] == e) for e in ("map_stop", "explored", "step_cap")},
            "false_stops": len(false),
            "false_stop_rate": len(false) / len(group) if group else None,
            "false_stop_runs": [f"{r['spec']['plan']} run {r['spec']['run']}" for r in false],
            "correct_coverage_at_stop": _stats([_correct_at_stop(r) for r in group]),
            "path_at_stop_m": _stats([_path_at_stop(r) for r in group]),
            "vs_reference": None,
        }
        if ref is not None:
            own = _per_building(records, m)
            d = np.array([own[p] - ref[p] for p in own if p in ref])
            ratio = np.array([own[p] / ref[p] for p in own if p in ref and ref[p] > 0])
            n = len(d)
            entry["vs_reference"] = {
                "reference": reference,
                "buildings": n,
                "mean_m": float(d.mean()) if n else None,
                "stderr_m": float(d.std(ddof=1) / math.sqrt(n)) if n > 1 else None,
                "median_m": float(np.median(d)) if n else None,
                "mean_ratio": float(ratio.mean()) if len(ratio) else None,
                "shorter": int((d < 0).sum()),
            }
        out[m] = entry
    return out


def markdown_stops(stops: dict[str, dict[str, Any]], threshold_m2: float) -> str:
    """The map stop rule's table: per method its endings, false stops and path at the stop against the
    reference's own end."""
    lines = [
        "",
        f"Map stop rule (unverified area < {threshold_m2:g} m²); false stop: correct coverage < "
        f"{100 * FALSE_STOP_CORRECT:.0f} % at the stop; path at the stop − {REFERENCE}'s own end, paired by building:",
        "",
        "| method | runs | map stops / explored / step cap | false stops | correct coverage at stop avg (min) "
        "| path at stop avg (m) | − frontier's end: mean ± s.e. (m) | median (m) | ratio | shorter on |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for m, s in stops.items():
        e, c, p, v = s["endings"], s["correct_coverage_at_stop"], s["path_at_stop_m"], s["vs_reference"]
        rate = "–" if s["false_stop_rate"] is None else f"{100 * s['false_stop_rate']:.1f} %"
        cov = "–" if c["avg"] is None else f"{100 * c['avg']:.1f} % ({100 * c['min']:.1f} %)"
        path = "–" if p["avg"] is None else f"{p['avg']:.1f}"
        if v is None or v["mean_m"] is None:
            paired = "– | – | – | –"
        else:
            se = "–" if v["stderr_m"] is None else f"{v['stderr_m']:.1f}"
            ratio = "–" if v["mean_ratio"] is None else f"×{v['mean_ratio']:.2f}"
            paired = f"{v['mean_m']:+.1f} ± {se} | {v['median_m']:+.1f} | {ratio} | {v['shorter']}/{v['buildings']}"
        lines.append(
            f"| {m} | {s['runs']} | {e['map_stop']} / {e['explored']} / {e['step_cap']} | {s['false_stops']} "
            f"({rate}) | {cov} | {path} | {paired} |"
        )
    return "\n".join(lines) + "\n"
