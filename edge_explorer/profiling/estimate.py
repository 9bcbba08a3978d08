"""The report's arithmetic: percentiles, estimates for other devices, compute needed, PASS/FAIL per budget.

**Estimates.** A target that is not this host is never measured: its latency for a stage is the host's measured
latency times the ratio of peak throughputs, host over target, for the engine the stage runs on there —

* stages that are not networks (fuse, project, ego, thresholding, waypoint + trajectory, …): single-core peak
  fp32 GFLOPS (the daemon runs them on one core);
* a network on a CPU backend: single-core peak int8 GOPS for an int8 artifact, fp32 GFLOPS for an fp32 one (the
  daemon runs inference on one thread);
* a network on the Edge TPU: the host's single-core int8 GOPS over the accelerator's peak int8 TOPS.

Peak ratios ignore memory bandwidth, caches, USB transfers and operator coverage, so an estimate is a first-order
answer, optimistic for accelerators; it is marked "estimate" wherever it appears. The paper's own measurements
are the profiles' budgets, printed beside them.

**Compute needed.** A network needs 2 operations per multiply-accumulate. Sustained: the operations of one
decision (predictor + policy) times the decision rate. To meet a budget: one inference's operations over the
stage's latency budget, against the peak of the engine that runs it — a roofline bound (necessary, not
sufficient: at 100 % utilisation the budget is just met).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from edge_explorer.runtime.device_profile import DeviceProfile

MODEL_STAGES: tuple[str, ...] = ("predictor", "policy")  # stages that are one network inference (plus glue)
BUDGETED_STAGES: tuple[str, ...] = ("fuse", "predictor", "policy", "decision")
# A whole decision, as wall-clock latency and as the loop thread's CPU time: both contain the model stages.
DECISION_STAGES: tuple[str, ...] = ("decision", "decision_cpu")
CPU_BACKENDS: tuple[str, ...] = ("litert-cpu", "onnxruntime-cpu")
PASS, FAIL, NA = "PASS", "FAIL", "n/a"


@dataclass(frozen=True)
class Percentiles:
    """Latency percentiles of one stage, milliseconds."""

    count: int
    mean_ms: float
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float

    def scaled(self, ratio: float) -> Percentiles:
        return Percentiles(
            self.count, *(ratio * v for v in (self.mean_ms, self.p50_ms, self.p95_ms, self.p99_ms, self.max_ms))
        )

    def to_json(self) -> dict[str, float]:
        return asdict(self)


def percentiles(samples_ms: np.ndarray) -> Percentiles:
    ms = np.asarray(samples_ms, dtype=np.float64)
    if ms.size == 0:
        raise ValueError("no samples")
    p50, p95, p99 = np.percentile(ms, [50, 95, 99])
    return Percentiles(int(ms.size), float(ms.mean()), float(p50), float(p95), float(p99), float(ms.max()))


@dataclass(frozen=True)
class Engine:
    """Where a network runs on a device: the backend, the artifact's precision, and the engine's peak (ops/s)."""

    backend: str
    precision: str
    peak_ops_per_s: float


def engine(profile: DeviceProfile, backend: str, precision: str) -> Engine:
    """The engine ``backend`` uses on ``profile``: the Edge TPU's peak, or one CPU core's for the precision."""
    if backend == "edgetpu":
        return Engine(backend, precision, profile.accelerator.peak_int8_tops * 1e12)
    per_core = profile.cpu.peak_int8_gops_per_core if precision == "int8" else profile.cpu.peak_fp32_gflops_per_core
    return Engine(backend, precision, per_core * 1e9)


def target_engine(profile: DeviceProfile, model: str, artifacts: list[tuple[str, str]]) -> Engine | None:
    """The engine the daemon's chain would pick on ``profile`` for ``model`` with ``artifacts`` [(backend,
    precision)]: the first backend of the profile's order for that model that has an artifact (int8 preferred, as the
    daemon asks), skipping the Edge TPU on a device without one. None when no backend of the order can run it."""
    for backend in profile.order_for(model):
        if backend == "edgetpu" and profile.accelerator.kind != "edgetpu":
            continue
        precisions = sorted({p for b, p in artifacts if b == backend}, key=lambda p: (p != "int8", p))
        if precisions:
            return engine(profile, backend, precisions[0])
    return None


def model_ratio(host_engine: Engine, target: Engine) -> float:
    """Host engine peak over target engine peak: the factor for a network measured on ``host_engine``."""
    return host_engine.peak_ops_per_s / target.peak_ops_per_s


@dataclass(frozen=True)
class Verdict:
    """One budget check. ``value`` and ``limit`` in ``unit``; ``estimate`` when the value is not measured."""

    check: str
    value: float | None
    limit: float
    unit: str
    status: str  # PASS, FAIL or n/a
    estimate: bool
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def verdict(
    check: str, value: float | None, limit: float, unit: str, estimate: bool, note: str = "", at_most: bool = True
) -> Verdict:
    """PASS when ``value`` is within ``limit`` (≤, or ≥ with ``at_most=False``), n/a when there is no value."""
    if value is None or not np.isfinite(value):
        return Verdict(check, None, limit, unit, NA, estimate, note)
    ok = value <= limit if at_most else value >= limit
    return Verdict(check, float(value), limit, unit, PASS if ok else FAIL, estimate, note)


def stage_estimates(
    host: DeviceProfile,
    target: DeviceProfile,
    measured: dict[str, Percentiles],
    model_engines: dict[str, tuple[Engine, Engine | None]],
) -> tuple[dict[str, Percentiles], dict[str, float]]:
    """Every measured stage on ``target`` (the host's own figures when ``target`` is the measured host) and the
    ratio applied to each. ``model_engines``: stage → (host engine it ran on, target engine or None).

    The decision (frame in → waypoint out, and its CPU time) is scaled as its parts are: the whole at the CPU ratio,
    corrected by the model stages' own ratios: d_t = r_cpu · d_h + Σ_models (r_model − r_cpu) · m_h, per percentile.
    """
    if target.measured:
        return dict(measured), dict.fromkeys(measured, 1.0)
    r_cpu = target.cpu_speed_ratio_fp32(host)
    ratios = {stage: r_cpu for stage in measured}
    for stage, (host_engine, target_eng) in model_engines.items():
        if stage in measured and target_eng is not None:
            ratios[stage] = model_ratio(host_engine, target_eng)
    out = {stage: p.scaled(ratios[stage]) for stage, p in measured.items()}
    fields = ("mean_ms", "p50_ms", "p95_ms", "p99_ms", "max_ms")
    for whole in DECISION_STAGES:
        if whole not in measured:
            continue
        d = measured[whole]
        values = [r_cpu * getattr(d, f) for f in fields]
        for stage in MODEL_STAGES:
            if stage in measured:
                values = [
                    v + (ratios[stage] - r_cpu) * getattr(measured[stage], f)
                    for v, f in zip(values, fields, strict=True)
                ]
        out[whole] = Percentiles(d.count, *values)
        ratios[whole] = out[whole].p95_ms / d.p95_ms if d.p95_ms > 0 else r_cpu
    return out, ratios


@dataclass(frozen=True)
class ComputeNeed:
    """Operations a network needs on a device: sustained at the decision rate, and to meet its latency budget."""

    model: str
    macs: float
    engine: str
    peak_tops: float
    sustained_tops: float  # 2 · MACs · decision rate
    budget_tops: float  # 2 · MACs / budget
    utilisation_at_budget: float  # budget_tops / peak_tops

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def compute_need(model: str, macs: float, target: Engine, decision_hz: float, budget_ms: float) -> ComputeNeed:
    ops = 2.0 * macs
    peak_tops = target.peak_ops_per_s / 1e12
    budget_tops = ops / (budget_ms / 1e3) / 1e12
    return ComputeNeed(
        model=model,
        macs=macs,
        engine=f"{target.backend} ({target.precision})",
        peak_tops=peak_tops,
        sustained_tops=ops * decision_hz / 1e12,
        budget_tops=budget_tops,
        utilisation_at_budget=budget_tops / peak_tops if peak_tops > 0 else float("inf"),
    )


def verdicts(
    profile: DeviceProfile,
    stages: dict[str, Percentiles],
    cpu_percent: float,
    peak_rss_mb: float,
    needs: list[ComputeNeed],
    missing: dict[str, str],
) -> list[Verdict]:
    """PASS/FAIL of every budget of ``profile`` (p95 latencies), its rates, ceilings and compute.

    ``missing``: stage → why it was not measured (a model that is not shipped), shown as n/a with the reason.
    """
    est = not profile.measured
    budgets = profile.budgets_ms
    out = []
    for stage in BUDGETED_STAGES:
        p = stages.get(stage)
        note = missing.get(stage, "") if p is None else ""
        out.append(verdict(f"{stage} p95", None if p is None else p.p95_ms, getattr(budgets, stage), "ms", est, note))
    fuse, decision = stages.get("fuse"), stages.get("decision")
    rates = profile.rates_hz
    out.append(
        verdict(
            f"fuse keeps up with {rates.depth:g} Hz depth (p95 ≤ frame period)",
            None if fuse is None else fuse.p95_ms,
            1e3 / rates.depth,
            "ms",
            est,
        )
    )
    out.append(
        verdict(
            f"decision keeps up with {rates.decision:g} Hz decisions (p95 ≤ period)",
            None if decision is None else decision.p95_ms,
            1e3 / rates.decision,
            "ms",
            est,
        )
    )
    out.append(verdict("daemon CPU (% of one core)", cpu_percent, profile.ceilings.cpu_percent_of_one_core, "%", est))
    out.append(verdict("peak RSS", peak_rss_mb, profile.memory.rss_ceiling_mb, "MB", est))
    for need in needs:
        out.append(
            verdict(
                f"{need.model} compute to meet its budget on {need.engine}",
                need.budget_tops,
                need.peak_tops,
                "TOPS",
                True,
                f"roofline bound: {100 * need.utilisation_at_budget:.1f} % of peak",
            )
        )
    return out
