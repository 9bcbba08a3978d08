"""The profiling report as one self-contained ``report.html``.

:func:`write_html` draws the document of :func:`~edge_explorer.profiling.report.build_report` with matplotlib, the
PNG figures embedded as base64 so that no network is needed to view it: latency CDFs per stage with the budgets as
vertical lines, a stacked bar of one decision's time per device, the models' latency per backend, and the verdict,
model and compute tables. It reads only the document (and the host's raw stage samples for the CDFs), so the
rendering lives apart from the measuring and the verdicts.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.profiling.estimate import BUDGETED_STAGES
from edge_explorer.profiling.report import STAGE_LABELS, fmt, orders_text, si

# The stages of one decision, in the order they run (the triggering frame's fusion first).
DECISION_PARTS: tuple[str, ...] = (
    "fuse",
    "project",
    "predictor",
    "thresholding",
    "coverage",
    "ego",
    "policy",
    "planner",
    "waypoint_trajectory",
)

_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _png(fig: Any) -> str:
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _figure_cdfs(doc: dict[str, Any], samples: dict[str, np.ndarray]) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    stages = [s for s in STAGE_LABELS if s in samples]
    cols = 3
    rows = -(-len(stages) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(15, 3.4 * rows), squeeze=False)
    for ax, stage in zip(axes.ravel(), stages, strict=False):
        host_ms = np.sort(samples[stage])
        y = np.arange(1, host_ms.size + 1) / host_ms.size
        for color, section in zip(_COLORS, doc["profiles"], strict=False):
            ratio = section["stage_ratios"].get(stage, 1.0)
            style = "-" if section["kind"] == "measured" else "--"
            label = section["name"] + ("" if section["kind"] == "measured" else " (estimate)")
            ax.step(host_ms * ratio, y, style, where="post", color=color, label=label, lw=1.4)
            if stage in BUDGETED_STAGES:
                budget = next(v for v in section["verdicts"] if v["check"] == f"{stage} p95")["limit"]
                ax.axvline(budget, color=color, ls=":", lw=1.2)
        ax.axhline(0.95, color="0.6", lw=0.6)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(STAGE_LABELS[stage] + (" · budgets dotted" if stage in BUDGETED_STAGES else ""), fontsize=10)
        ax.set_xlabel("latency (ms, log)")
        ax.set_ylabel("fraction ≤ x")
        ax.grid(alpha=0.3, which="both")
    for ax in axes.ravel()[len(stages) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle("Latency CDF per stage: host measured (solid), other devices estimated (dashed)", fontsize=12)
    fig.tight_layout()
    return _png(fig)


def _figure_decision(doc: dict[str, Any]) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sections = doc["profiles"]
    fig, ax = plt.subplots(figsize=(13, 1.2 + 0.8 * len(sections)))
    cmap = plt.get_cmap("tab10")
    parts = [p for p in DECISION_PARTS if any(p in s["stages"] for s in sections)]
    for row, section in enumerate(sections):
        left = 0.0
        for k, part in enumerate(parts):
            value = section["stages"].get(part, {}).get("p50_ms", 0.0)
            ax.barh(row, value, left=left, color=cmap(k % 10), label=STAGE_LABELS[part] if row == 0 else None)
            left += value
        budget = next(v for v in section["verdicts"] if v["check"] == "decision p95")["limit"]
        ax.plot([budget, budget], [row - 0.45, row + 0.45], color="black", lw=2)
        ax.text(budget, row + 0.47, f" budget {budget:g} ms", fontsize=8, va="bottom")
        ax.text(left, row, f" {left:.1f} ms", va="center", fontsize=9)
    ax.set_yticks(range(len(sections)))
    ax.set_yticklabels([s["name"] + ("" if s["kind"] == "measured" else "\n(estimate)") for s in sections])
    ax.invert_yaxis()
    ax.set_xlim(0, 1.18 * max(ax.get_xlim()[1], 1.0))
    ax.set_xlabel("milliseconds (median of each stage)")
    ax.set_title("One decision, stage by stage (the triggering frame's fusion included)")
    ax.legend(fontsize=8, ncol=5, loc="upper center", bbox_to_anchor=(0.5, -0.35 if len(sections) > 2 else -0.6))
    fig.tight_layout()
    return _png(fig)


def _figure_models(doc: dict[str, Any]) -> str | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [
        (f"{m['name']}\n{r['backend']} {r['precision']}", r["latency_ms"])
        for m in doc["models"]
        for r in m["runs"]
        if r["latency_ms"] is not None
    ]
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(10, 1.0 + 0.55 * len(rows)))
    p50 = [r[1]["p50_ms"] for r in rows]
    p95 = [r[1]["p95_ms"] for r in rows]
    ax.barh(range(len(rows)), p50, color="tab:blue", label="p50")
    ax.errorbar(p50, range(len(rows)), xerr=[np.zeros(len(rows)), np.subtract(p95, p50)], fmt="none", color="k")
    for i, (v, top) in enumerate(zip(p50, p95, strict=True)):
        ax.text(top, i, f"  p50 {v:.2f} ms", va="center", fontsize=9)
    ax.set_xlim(0, 1.25 * max(p95))
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([r[0] for r in rows], fontsize=9)
    ax.invert_yaxis()
    ax.set_xlabel("one inference on this host (ms; bar p50, whisker p95)")
    ax.set_title("Every model on every backend available here (measured)")
    fig.tight_layout()
    return _png(fig)


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]], classes: Sequence[str] | None = None) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = []
    for i, row in enumerate(rows):
        cls = f' class="{classes[i]}"' if classes and classes[i] else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;max-width:1500px;color:#222}
table{border-collapse:collapse;margin:8px 0 18px}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}
th{background:#f2f2f2;text-align:left}tr.PASS td:last-child{background:#d7f5d7}tr.FAIL td:last-child{background:#f8d0d0}
tr.na td:last-child{background:#eee}.est{color:#a15c00;font-weight:600}img{max-width:100%}
h2{border-bottom:2px solid #ddd;padding-bottom:4px}.overall-PASS{color:#1a7f1a}.overall-FAIL{color:#b00}
code{background:#f4f4f4;padding:1px 4px}
"""


def write_html(path: Path, doc: dict[str, Any], samples: dict[str, np.ndarray]) -> None:
    """The self-contained report (figures as base64 PNG)."""
    loop = doc["loop"]
    out = [
        "<!doctype html><html><head><meta charset='utf-8'><title>edge-explorer latency profile</title>",
        f"<style>{_CSS}</style></head><body>",
        "<h1>edge-explorer latency profile</h1>",
        f"<p><code>{html.escape(doc['command'])}</code> · {doc['created_utc']} · host load average "
        f"{doc['host']['load_average_1min']:.2f}</p>",
        f"<p><b>Measured</b> on this host ({html.escape(doc['host']['description'])}; {doc['host']['machine']}): "
        f"{loop['decisions']} decisions and {loop['frames_fused']} depth frames of the daemon's real loop against the "
        f"simulated vehicle on plan {html.escape(loop['plan'])} over MAVLink on loopback UDP ({loop['planner']} "
        f"planner). Daemon CPU {loop['daemon_cpu_percent_of_one_core']:.1f} % of one core (process "
        f"{loop['process_cpu_percent_of_one_core']:.1f} % incl. the simulated vehicle and camera), peak RSS "
        f"{loop['peak_rss_mb']:.0f} MB. <span class='est'>Every figure for another device is an estimate</span> "
        "scaled from these measurements by the ratio of peak throughputs (see the notes at the end).</p>",
        "<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in loop["model_notes"]) + "</ul>",
        "<h2>Verdicts</h2>",
    ]
    for section in doc["profiles"]:
        kind = "measured on this host" if section["kind"] == "measured" else "ESTIMATE scaled from the host"
        out.append(
            f"<h3>{html.escape(section['name'])} — <span class='overall-{section['overall']}'>"
            f"{section['overall']}</span> <span class='{'est' if section['kind'] != 'measured' else ''}'>({kind})"
            f"</span></h3><p>{html.escape(section['description'])}. Backend order: "
            f"{html.escape(orders_text(section))}</p>"
        )
        rows, classes = [], []
        for v in section["verdicts"]:
            value = fmt(v["value"], v["unit"]) + (" (estimate)" if v["estimate"] and v["value"] is not None else "")
            rows.append(
                [v["check"], value, fmt(v["limit"], v["unit"]), v["status"] + (f" — {v['note']}" if v["note"] else "")]
            )
            classes.append(v["status"] if v["status"] != "n/a" else "na")
        out.append(_table(["check", "value", "limit", "verdict"], rows, classes))
    out.append("<h2>Latency per stage</h2>")
    out.append(f"<img alt='latency CDFs' src='data:image/png;base64,{_figure_cdfs(doc, samples)}'>")
    out.append(f"<img alt='one decision' src='data:image/png;base64,{_figure_decision(doc)}'>")
    headers = ["stage", *[f"{s['name']} p50 / p95 / p99 / max (ms)" for s in doc["profiles"]]]
    rows = []
    for stage in loop["stages"]:
        row = [STAGE_LABELS.get(stage, stage)]
        for s in doc["profiles"]:
            p = s["stages"][stage]
            mark = "" if s["kind"] == "measured" else " est."
            row.append(f"{p['p50_ms']:.2f} / {p['p95_ms']:.2f} / {p['p99_ms']:.2f} / {p['max_ms']:.1f}{mark}")
        rows.append(row)
    out.append(_table(headers, rows))
    out.append("<h2>Models</h2>")
    model_png = _figure_models(doc)
    if model_png is not None:
        out.append(f"<img alt='models' src='data:image/png;base64,{model_png}'>")
    rows = []
    for m in doc["models"]:
        if not m["present"]:
            rows.append([m["name"], "–", "–", "–", "–", f"unavailable: {m['note']}"])
            continue
        for r in m["runs"]:
            lat = r["latency_ms"]
            value = (
                "not measured" if lat is None else f"{lat['p50_ms']:.2f} / {lat['p95_ms']:.2f} / {lat['max_ms']:.2f}"
            )
            rows.append([m["name"], r["backend"], r["precision"], r["artifact"] or "–", value, r["note"]])
    out.append(_table(["model", "backend", "precision", "artifact", "host p50 / p95 / max (ms)", "chain report"], rows))
    rows = [
        [m["name"], si(m["macs"]), si(m["params"]), m["size_source"], _edgetpu_text(m["edgetpu_compatibility"])]
        for m in doc["models"]
        if m["present"]
    ]
    if rows:
        out.append(
            _table(["model", "MACs / inference", "parameters", "counted from", "Edge TPU compatibility (export)"], rows)
        )
    out.append("<h2>Per device: where the models run, compute needed</h2>")
    for section in doc["profiles"]:
        est = section["kind"] != "measured"
        out.append(f"<h3>{html.escape(section['name'])}{' (estimate)' if est else ''}</h3>")
        peaks = section["peaks"]
        accelerator = peaks["accelerator"]
        if accelerator != "none":
            accelerator += f" {peaks['accelerator_int8_tops']:g} TOPS int8"
        out.append(
            f"<p>{html.escape(peaks['cpu'])}: {peaks['cores']} cores, {peaks['fp32_gflops_per_core']:g} GFLOPS fp32 "
            "and "
            f"{peaks['int8_gops_per_core']:g} GOPS int8 per core; accelerator {accelerator}. "
            f"Non-network stages ×{section['cpu_ratio']:.2f} of the host's time. Sustained compute at the decision "
            f"rate: {section['sustained_tops_per_decision_rate']:.3g} TOPS.</p>"
        )
        rows = []
        for m in section["models"]:
            lat = m.get("latency_ms")
            value = (
                "–" if lat is None else f"{lat['p50_ms']:.2f} / {lat['p95_ms']:.2f}" + (" (estimate)" if est else "")
            )
            scale = "" if not m.get("scaled_from") else f"{m['scaled_from']} × {m['ratio']:.3g}"
            rows.append([m["model"], m["engine"] or "–", value, scale, m["note"]])
        out.append(_table(["model", "runs on", "p50 / p95 (ms)", "scaled from", "note"], rows))
        rows = [
            [
                c["model"],
                c["engine"],
                si(c["macs"]),
                f"{c['sustained_tops']:.3g}",
                f"{c['budget_tops']:.3g}",
                f"{c['peak_tops']:.3g}",
                f"{100 * c['utilisation_at_budget']:.1f} %",
            ]
            for c in section["compute"]
        ]
        if rows:
            out.append(
                _table(
                    ["model", "engine", "MACs", "TOPS at decision rate", "TOPS to meet budget", "peak TOPS", "of peak"],
                    rows,
                )
            )
    out.append(
        "<h2>Notes</h2><ul>"
        "<li>Percentiles after warm-up; the budgets are checked at p95.</li>"
        "<li>Estimates: host latency × (host peak / target peak) of the engine each stage runs on: one CPU core's fp32 "
        "GFLOPS for non-network stages, one core's int8 GOPS (or fp32 GFLOPS) for a network on a CPU backend, the "
        "accelerator's int8 TOPS for the Edge TPU. Peak ratios ignore memory bandwidth, caches, USB transfers and "
        "operator coverage: first-order figures, optimistic for accelerators. The paper measured the predictor at "
        "135 ms on an i7-10710U and 150 ms on a 4-TOPS Coral, the policy at 8 ms and the whole stack at 32.7 % of "
        "that CPU; those are the nuc10 and coral budgets.</li>"
        "<li>Coverage is measured against the simulated building's plan: a simulation-only stage.</li>"
        "<li>Peak RSS is the profiling process's (the simulated world included); on other devices it is assumed the "
        "same (estimate).</li></ul></body></html>"
    )
    path.write_text("\n".join(out))


def _edgetpu_text(entry: Any) -> str:
    if entry is None:
        return "not in the card"
    if isinstance(entry, dict):
        return "; ".join(f"{k}: {v}" for k, v in entry.items())
    return str(entry)
