"""The profiling report: the ``report.json`` document and its Markdown summary.

:func:`build_report` turns the host's measurements (the daemon's loop, every model on every backend) into one
document with a section per requested device profile: the host's figures as measured, every other device's as
estimates (:mod:`edge_explorer.profiling.estimate`), each with its compute needs and its PASS/FAIL verdicts;
:func:`markdown_summary` is its terminal summary. The self-contained ``report.html`` drawn from the same document is
:mod:`edge_explorer.profiling.html_report`'s.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Sequence
from typing import Any

from edge_explorer.backends.chain import BACKENDS
from edge_explorer.profiling.estimate import (
    CPU_BACKENDS,
    FAIL,
    MODEL_STAGES,
    PASS,
    Engine,
    compute_need,
    engine,
    model_ratio,
    percentiles,
    stage_estimates,
    target_engine,
    verdicts,
)
from edge_explorer.profiling.loop import LoopMeasurement
from edge_explorer.profiling.models import BackendRun, ModelInfo
from edge_explorer.runtime.device_profile import MODEL_NAMES, DeviceProfile

REPORT_FORMAT = "edge-explorer/profile-report"
STAGE_LABELS: dict[str, str] = {
    "fuse": "fuse (one depth frame)",
    "project": "project (3-D → 2-D maps)",
    "ego": "ego transform (policy observation)",
    "predictor": "predictor (window + network)",
    "thresholding": "thresholding",
    "coverage": "coverage (simulation only)",
    "policy": "policy (network)",
    "planner": "frontier planner / way home",
    "waypoint_trajectory": "waypoint + trajectory",
    "mavlink_io": "MAVLink I/O",
    "decision": "decision (frame in → waypoint out)",
    "decision_cpu": "decision CPU time (loop thread; unaffected by other processes)",
}


# ---------------------------------------------------------------------------------------------------------------
# The document
# ---------------------------------------------------------------------------------------------------------------


def _card_engines(info: ModelInfo) -> list[tuple[str, str]]:
    """(backend, precision) pairs the card offers, over every backend (not only the ones measured here)."""
    from edge_explorer.backends.card import load_card

    card = load_card(info.card)
    return sorted(
        {
            (b, a.precision)
            for a in card.artifacts.values()
            for b, cls in BACKENDS.items()
            if cls.artifact_format == a.format
        }
    )


def _host_run_for(info: ModelInfo, target: Engine) -> BackendRun | None:
    """The host measurement an estimate for ``target`` scales from: the same artifact on the same CPU backend, or
    for the Edge TPU the int8 TFLite artifact on LiteRT's CPU backend."""
    backend = "litert-cpu" if target.backend == "edgetpu" else target.backend
    for run in info.runs:
        if run.backend == backend and run.precision == target.precision and run.samples_ms is not None:
            return run
    return None


def _model_rows(host: DeviceProfile, profile: DeviceProfile, models: Sequence[ModelInfo]) -> list[dict[str, Any]]:
    """Per model: where the profile's chain would run it, and its latency there (measured on the host, else an
    estimate scaled from the host's run of the same artifact)."""
    rows = []
    for info in models:
        if not info.present:
            rows.append({"model": info.name, "engine": None, "note": f"unavailable: {info.note}"})
            continue
        target = target_engine(profile, info.name, _card_engines(info))
        if target is None:
            rows.append({"model": info.name, "engine": None, "note": "no backend of the profile's order can run it"})
            continue
        base = _host_run_for(info, target)
        if base is None:
            note = f"{target.backend} ({target.precision}): no host measurement of that artifact to scale from"
            rows.append({"model": info.name, "engine": f"{target.backend} ({target.precision})", "note": note})
            continue
        host_engine = engine(host, base.backend, base.precision)
        ratio = 1.0 if profile.measured else model_ratio(host_engine, target)
        note = ""
        if profile.accelerator.kind == "edgetpu" and target.backend != "edgetpu":
            tpu_ms = percentiles(base.samples_ms).p50_ms * model_ratio(host_engine, engine(profile, "edgetpu", "int8"))
            note = (
                f"no Edge TPU artifact in the card (edgetpu_compiler): the CPU runs it; compiled, ~{tpu_ms:.1f} ms p50 "
                "(estimate at the Edge TPU's peak)"
            )
        rows.append(
            {
                "model": info.name,
                "engine": f"{target.backend} ({target.precision})",
                "artifact": base.artifact,
                "scaled_from": None if profile.measured else f"host {base.backend} ({base.precision})",
                "ratio": ratio,
                "estimate": not profile.measured,
                "latency_ms": percentiles(base.samples_ms).scaled(ratio).to_json(),
                "note": note,
            }
        )
    return rows


def _profile_section(
    host: DeviceProfile, profile: DeviceProfile, loop: LoopMeasurement, models: Sequence[ModelInfo]
) -> dict[str, Any]:
    measured = {stage: percentiles(ms) for stage, ms in loop.samples_ms.items()}
    infos = {m.name: m for m in models}
    model_engines: dict[str, tuple[Engine, Engine | None]] = {}
    for stage in MODEL_STAGES:
        if stage in loop.engines and stage in infos and infos[stage].present:
            backend, precision, _ = loop.engines[stage]
            model_engines[stage] = (
                engine(host, backend, precision),
                target_engine(profile, stage, _card_engines(infos[stage])),
            )
    stages, ratios = stage_estimates(host, profile, measured, model_engines)
    # CPU: the non-network share scales with the CPU ratio, a network's with its engine's (none on an accelerator).
    r_cpu = 1.0 if profile.measured else profile.cpu_speed_ratio_fp32(host)
    network_cpu = {
        s: measured[s].mean_ms * len(loop.samples_ms[s]) / (10.0 * loop.wall_s) for s in model_engines if s in measured
    }
    cpu = r_cpu * (loop.daemon_cpu_percent - sum(network_cpu.values()))
    for stage, share in network_cpu.items():
        target = model_engines[stage][1]
        on_cpu = target is None or target.backend in CPU_BACKENDS
        cpu += share * (ratios[stage] if on_cpu else 0.0)
    needs = []
    for info in models:
        if info.present and info.size.macs is not None:
            target = target_engine(profile, info.name, _card_engines(info))
            if target is not None:
                budget = getattr(profile.budgets_ms, info.name)
                needs.append(compute_need(info.name, info.size.macs, target, profile.rates_hz.decision, budget))
    missing = {}
    for stage in MODEL_STAGES:
        if stage not in measured:
            info = infos.get(stage)
            why = info.note if info is not None and not info.present else "not loaded by the daemon"
            missing[stage] = f"no {stage} ran: {why}"
    checks = verdicts(profile, stages, cpu, loop.peak_rss_mb, needs, missing)
    failed = [v.check for v in checks if v.status == FAIL]
    return {
        "name": profile.name,
        "description": profile.description,
        "kind": "measured" if profile.measured else "estimate",
        "source": profile.source,
        "backend_orders": {model: list(profile.order_for(model)) for model in MODEL_NAMES},
        "peaks": {
            "cpu": profile.cpu.model,
            "cores": profile.cpu.cores,
            "fp32_gflops_per_core": profile.cpu.peak_fp32_gflops_per_core,
            "int8_gops_per_core": profile.cpu.peak_int8_gops_per_core,
            "accelerator": profile.accelerator.kind,
            "accelerator_int8_tops": profile.accelerator.peak_int8_tops,
        },
        "cpu_ratio": r_cpu,
        "stage_ratios": ratios,
        "stages": {s: p.to_json() for s, p in stages.items()},
        "models": _model_rows(host, profile, models),
        "compute": [n.to_json() for n in needs],
        "sustained_tops_per_decision_rate": sum(n.sustained_tops for n in needs),
        "cpu_percent_of_one_core": cpu,
        "peak_rss_mb": loop.peak_rss_mb,
        "verdicts": [v.to_json() for v in checks],
        "overall": FAIL if failed else PASS,
        "failed": failed,
    }


def _model_json(info: ModelInfo) -> dict[str, Any]:
    runs = []
    for run in info.runs:
        entry = {"backend": run.backend, "precision": run.precision, "artifact": run.artifact, "note": run.note}
        entry["latency_ms"] = None if run.samples_ms is None else percentiles(run.samples_ms).to_json()
        runs.append(entry)
    return {
        "name": info.name,
        "present": info.present,
        "card": str(info.card),
        "note": info.note,
        "macs": info.size.macs,
        "params": info.size.params,
        "size_source": info.size.source,
        "edgetpu_compatibility": info.edgetpu,
        "runs": runs,
    }


def build_report(
    host: DeviceProfile,
    profiles: Sequence[DeviceProfile],
    loop: LoopMeasurement,
    models: Sequence[ModelInfo],
    command: str,
) -> dict[str, Any]:
    """The report document (what ``report.json`` holds)."""
    return {
        "format": REPORT_FORMAT,
        "version": 1,
        "command": command,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "host": {
            "profile": host.name,
            "description": host.description,
            "machine": f"{platform.machine()}, {os.cpu_count()} logical CPUs, Python {platform.python_version()}",
            "load_average_1min": os.getloadavg()[0],
        },
        "loop": {
            "plan": loop.plan,
            "decisions": loop.decisions,
            "frames_fused": loop.frames_fused,
            "wall_s": loop.wall_s,
            "ending": loop.ending,
            "planner": loop.planner,
            "recording": loop.recording,
            "engines": {k: {"backend": b, "precision": p, "artifact": a} for k, (b, p, a) in loop.engines.items()},
            "model_notes": list(loop.model_notes),
            "daemon_cpu_percent_of_one_core": loop.daemon_cpu_percent,
            "process_cpu_percent_of_one_core": loop.process_cpu_percent,
            "peak_rss_mb": loop.peak_rss_mb,
            "stages": {s: percentiles(ms).to_json() for s, ms in loop.samples_ms.items()},
        },
        "models": [_model_json(m) for m in models],
        "profiles": [_profile_section(host, p, loop, models) for p in profiles],
    }


# ---------------------------------------------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------------------------------------------


def fmt(value: float | None, unit: str = "") -> str:
    """A figure for the tables: ``–`` when unknown, TOPS to three significant digits, else with its unit."""
    if value is None:
        return "–"
    if unit == "TOPS":
        return f"{value:.3g} TOPS"
    return f"{value:.2f} {unit}".strip() if abs(value) < 100 else f"{value:.0f} {unit}".strip()


def orders_text(section: dict[str, Any]) -> str:
    """``predictor: a → b; policy: c → d`` (the order each model's backends are tried in on that device)."""
    return "; ".join(f"{model}: {' → '.join(order) or 'none'}" for model, order in section["backend_orders"].items())


def markdown_summary(doc: dict[str, Any]) -> str:
    """The terminal summary: the measured loop, the models, and each profile's verdicts."""
    loop = doc["loop"]
    lines = [
        f"# Latency profile ({doc['created_utc']})",
        "",
        f"Measured on this host ({doc['host']['description']}): {loop['decisions']} decisions and "
        f"{loop['frames_fused']} frames of the daemon's real loop on plan {loop['plan']} ({loop['planner']} planner), "
        f"daemon CPU {loop['daemon_cpu_percent_of_one_core']:.1f} % of one core, "
        f"peak RSS {loop['peak_rss_mb']:.0f} MB; host load average {doc['host']['load_average_1min']:.2f}.",
        *[f"- {note}" for note in loop["model_notes"]],
        "",
        "| stage (host, measured) | n | p50 ms | p95 ms | p99 ms | max ms |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for stage, p in loop["stages"].items():
        lines.append(
            f"| {STAGE_LABELS.get(stage, stage)} | {p['count']} | {p['p50_ms']:.2f} | {p['p95_ms']:.2f} | "
            f"{p['p99_ms']:.2f} | {p['max_ms']:.2f} |"
        )
    lines += [
        "",
        "| model | backend | precision | p50 ms | p95 ms | MACs | params |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for m in doc["models"]:
        if not m["present"]:
            lines.append(f"| {m['name']} | – | – | – | – | – | unavailable: {m['note']} |")
            continue
        size = (si(m["macs"]), si(m["params"]))
        for run in m["runs"]:
            lat = run["latency_ms"]
            p50, p95 = ("–", "–") if lat is None else (f"{lat['p50_ms']:.2f}", f"{lat['p95_ms']:.2f}")
            if lat is None:
                p95 = f"not here: {run['note'][:80]}"
            lines.append(
                f"| {m['name']} | {run['backend']} | {run['precision']} | {p50} | {p95} | {size[0]} | {size[1]} |"
            )
    for section in doc["profiles"]:
        kind = "measured" if section["kind"] == "measured" else "ESTIMATE scaled from the host"
        lines += [
            "",
            f"## {section['name']} ({kind}): {section['overall']}",
            "",
            f"Backend order: {orders_text(section)}",
            "",
            "| check | value | limit | verdict |",
            "| --- | ---: | ---: | --- |",
        ]
        for v in section["verdicts"]:
            value = fmt(v["value"], v["unit"]) + (" (estimate)" if v["estimate"] and v["value"] is not None else "")
            note = f" — {v['note']}" if v["note"] else ""
            lines.append(f"| {v['check']} | {value} | {fmt(v['limit'], v['unit'])} | {v['status']}{note} |")
    return "\n".join(lines)


def si(value: float | None) -> str:
    """A count with an SI prefix (``1.23 G``); ``unknown`` when not counted."""
    if value is None:
        return "unknown"
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            return f"{value / scale:.2f} {suffix}"
    return f"{value:.0f}"
