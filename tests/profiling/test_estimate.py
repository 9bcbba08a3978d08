"""The report's arithmetic: estimates scaled by peak-throughput ratios, compute needed, PASS/FAIL/n/a."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from edge_explorer.profiling.estimate import (
    FAIL,
    NA,
    PASS,
    Percentiles,
    compute_need,
    engine,
    percentiles,
    stage_estimates,
    target_engine,
    verdict,
    verdicts,
)
from edge_explorer.runtime.device_profile import load_profile

HOST = load_profile("host")
NUC = load_profile("nuc10-i7-10710u")
CORAL = load_profile("coral-usb")
HOST_FP32 = HOST.cpu.peak_fp32_gflops_per_core  # the host's per-core peaks, as profiles/host.toml states them
HOST_INT8 = HOST.cpu.peak_int8_gops_per_core * 1e9


def flat(ms: float, count: int = 10) -> Percentiles:
    return Percentiles(count, ms, ms, ms, ms, ms)


def test_percentiles_of_known_samples():
    p = percentiles(np.arange(1.0, 101.0))
    assert (p.count, p.p50_ms, p.max_ms) == (100, 50.5, 100.0)
    assert p.p95_ms == pytest.approx(95.05) and p.p99_ms == pytest.approx(99.01)
    with pytest.raises(ValueError, match="no samples"):
        percentiles(np.array([]))


def test_the_host_is_reported_as_measured_without_scaling():
    measured = {"fuse": flat(7.0), "decision": flat(30.0)}
    stages, ratios = stage_estimates(HOST, HOST, measured, {})
    assert stages == measured and set(ratios.values()) == {1.0}


def test_non_network_stages_scale_by_the_single_core_fp32_peak_ratio():
    # host HOST_FP32 GFLOPS/core (profiles/host.toml), NUC 96: the NUC is estimated at HOST_FP32/96 of the host
    assert NUC.cpu_speed_ratio_fp32(HOST) == pytest.approx(HOST_FP32 / 96.0)
    stages, ratios = stage_estimates(HOST, NUC, {"fuse": flat(12.0)}, {})
    assert stages["fuse"].p95_ms == pytest.approx(12.0 * HOST_FP32 / 96.0)
    assert ratios["fuse"] == pytest.approx(HOST_FP32 / 96.0)


def test_networks_scale_by_their_engines_peak_and_the_decision_by_its_parts():
    host_int8 = engine(HOST, "litert-cpu", "int8")
    tpu = engine(CORAL, "edgetpu", "int8")
    assert host_int8.peak_ops_per_s == pytest.approx(HOST_INT8) and tpu.peak_ops_per_s == pytest.approx(4e12)
    measured = {"fuse": flat(10.0), "predictor": flat(20.0), "decision": flat(50.0), "decision_cpu": flat(30.0)}
    stages, ratios = stage_estimates(HOST, CORAL, measured, {"predictor": (host_int8, tpu)})
    r_cpu, r_tpu = HOST_FP32 / 12.0, HOST_INT8 / 4e12
    assert ratios["predictor"] == pytest.approx(r_tpu)
    assert stages["predictor"].p50_ms == pytest.approx(20.0 * r_tpu)
    assert stages["fuse"].p50_ms == pytest.approx(10.0 * r_cpu)
    # the decision: its non-network part at the CPU ratio, the predictor's part at the TPU's
    assert stages["decision"].p95_ms == pytest.approx(r_cpu * 50.0 + (r_tpu - r_cpu) * 20.0)
    assert stages["decision_cpu"].p50_ms == pytest.approx(r_cpu * 30.0 + (r_tpu - r_cpu) * 20.0)


def test_the_chain_order_decides_the_target_engine():
    artifacts = [("onnxruntime-cpu", "fp32"), ("onnxruntime-cpu", "int8"), ("litert-cpu", "int8")]
    assert target_engine(NUC, "predictor", artifacts) == engine(NUC, "litert-cpu", "int8")
    assert target_engine(CORAL, "predictor", [*artifacts, ("edgetpu", "int8")]).backend == "edgetpu"
    assert target_engine(CORAL, "predictor", artifacts).backend == "litert-cpu"  # no compiled model: the A72 runs it
    no_tpu = replace(HOST, backend_order=("edgetpu", "onnxruntime-cpu"))
    assert (
        target_engine(no_tpu, "predictor", [("edgetpu", "int8"), ("onnxruntime-cpu", "fp32")]).backend
        == "onnxruntime-cpu"
    )
    assert target_engine(NUC, "predictor", [("edgetpu", "int8")]) is None


def test_compute_need_arithmetic():
    need = compute_need("predictor", 1e9, engine(CORAL, "edgetpu", "int8"), decision_hz=2.0, budget_ms=100.0)
    assert need.sustained_tops == pytest.approx(2e9 * 2.0 / 1e12)
    assert need.budget_tops == pytest.approx(2e9 / 0.1 / 1e12)
    assert need.utilisation_at_budget == pytest.approx(0.02 / 4.0)


def test_verdict_logic():
    assert verdict("x", 10.0, 10.0, "ms", False).status == PASS  # at the limit is within it
    assert verdict("x", 10.01, 10.0, "ms", False).status == FAIL
    assert verdict("x", None, 10.0, "ms", True, "no model").status == NA
    assert verdict("x", float("nan"), 10.0, "ms", True).status == NA
    assert verdict("rate", 5.0, 10.0, "Hz", False, at_most=False).status == FAIL


def test_verdicts_cover_every_budget_and_say_why_a_stage_is_missing():
    stages = {"fuse": flat(5.0), "predictor": flat(20.0), "decision": flat(40.0)}
    need = compute_need("predictor", 1e12, engine(HOST, "litert-cpu", "int8"), 1.0, HOST.budgets_ms.predictor)
    out = {v.check: v for v in verdicts(HOST, stages, 12.0, 500.0, [need], {"policy": "no policy ran: missing"})}
    assert out["fuse p95"].status == PASS
    assert out["predictor p95"].status == FAIL  # 20 ms > 15 ms
    assert out["policy p95"].status == NA and out["policy p95"].note == "no policy ran: missing"
    assert out["decision p95"].status == PASS
    assert out["daemon CPU (% of one core)"].status == PASS
    assert out["peak RSS"].status == FAIL  # 500 MB > 300 MB
    compute = out["predictor compute to meet its budget on litert-cpu (int8)"]
    assert compute.status == FAIL and compute.estimate  # 2e12 ops in 15 ms on one host core (far over its int8 peak)
    assert not out["fuse p95"].estimate
    assert all(v.estimate for v in verdicts(CORAL, stages, 12.0, 100.0, [], {}))
