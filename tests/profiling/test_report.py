"""A short real run of the daemon's loop with a tiny ONNX predictor (no policy shipped) into the full report."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from edge_explorer.cli import main
from edge_explorer.profiling.html_report import write_html
from edge_explorer.profiling.loop import RECORDED_TIMINGS, LoopOptions, measure_loop
from edge_explorer.profiling.models import bench_models
from edge_explorer.profiling.report import build_report, markdown_summary
from edge_explorer.runtime.depth_sources import ReplayDepthSource
from edge_explorer.runtime.device_profile import load_profile
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan
from tests.predict.test_predictor import write_predictor_model

PROFILES = ("host", "coral-usb")


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """Three warm decisions on the two-room plan, starting airborne (a short climb)."""
    root = tmp_path_factory.mktemp("profile")
    write_predictor_model(root / "models" / "predictor", window=64)
    save_plan_json(two_room_plan(), root / "rooms.json")
    options = LoopOptions(
        models_dir=root / "models",
        backend_order=("litert-cpu", "onnxruntime-cpu"),
        plan=str(root / "rooms.json"),
        decisions=3,
        warmup_decisions=1,
        start_height_m=1.2,
        record_dir=root / "recording",
        daemon=replace(LoopOptions.daemon, takeoff_speed_mps=1.0, offboard_warmup_s=0.3),
    )
    seen = []
    loop = measure_loop(options, seen.append)
    models = bench_models(root / "models", ("litert-cpu", "onnxruntime-cpu"), repeats=5, warmup=1)
    return root, loop, models, sum(seen)


def test_the_loop_is_measured_after_warm_up(measured):
    _, loop, _, seen = measured
    assert loop.decisions == 3 and seen >= 4  # warm-up + measured, all reported to the progress callback
    for stage in ("fuse", "project", "predictor", "thresholding", "planner", "waypoint_trajectory", "mavlink_io"):
        assert stage in loop.samples_ms and (loop.samples_ms[stage] > 0).all()
    assert len(loop.samples_ms["predictor"]) == 3 and "policy" not in loop.samples_ms  # no policy shipped
    assert loop.engines["predictor"] == ("onnxruntime-cpu", "fp32", "predictor_fp32.onnx")
    assert 0 < loop.daemon_cpu_percent <= loop.process_cpu_percent and loop.peak_rss_mb > 10


def test_the_recording_holds_every_fused_frame_and_the_loops_own_timings(measured):
    """What scripts/independent_check.py replays: the frames, their poses and the loop's per-call times."""
    root, loop, _, _ = measured
    assert loop.recording == str(root / "recording")
    timings = json.loads((root / "recording" / RECORDED_TIMINGS).read_text())
    replay = ReplayDepthSource(root / "recording")
    fuse_ms = timings["samples_ms"]["fuse"]
    assert len(replay) == len(fuse_ms) and replay.next_frame().pose is not None
    np.testing.assert_allclose(fuse_ms[timings["window_start"]["fuse"] :], loop.samples_ms["fuse"], atol=1e-4)
    np.testing.assert_allclose(
        timings["samples_ms"]["predictor"][timings["window_start"]["predictor"] :],
        loop.samples_ms["predictor"],
        atol=1e-4,
    )
    assert timings["samples_ms"]["policy"] == []  # no policy shipped here: nothing for the check to replay
    cpu_from = timings["fuse_cpu_from"]  # the fuse calls' thread CPU, metered from the first frames on
    assert cpu_from <= timings["window_start"]["fuse"] and len(timings["fuse_cpu_ms"]) == len(fuse_ms) - cpu_from
    assert len(timings["fuse_preempted"]) == len(timings["fuse_cpu_ms"]) and min(timings["fuse_preempted"]) >= 0
    assert all(cpu <= wall + 0.5 for cpu, wall in zip(timings["fuse_cpu_ms"], fuse_ms[cpu_from:], strict=True))
    frames = timings["decision_frames"]
    assert len(frames) == 1 + 3 and frames == sorted(frames) and 0 < frames[-1] <= len(fuse_ms)


def test_a_replayed_flight_fuses_the_recorded_frames_with_their_poses(measured, tmp_path):
    root, first, _, _ = measured
    options = LoopOptions(
        models_dir=root / "models",
        backend_order=("onnxruntime-cpu",),
        plan=str(root / "rooms.json"),
        decisions=1,
        warmup_decisions=1,
        start_height_m=1.2,
        record_dir=tmp_path / "again",
        replay_dir=root / "recording",
        daemon=replace(LoopOptions.daemon, takeoff_speed_mps=1.0, offboard_warmup_s=0.3),
    )
    loop = measure_loop(options)
    assert loop.decisions == 1 and loop.frames_fused > 0
    original, again = ReplayDepthSource(root / "recording"), ReplayDepthSource(tmp_path / "again")
    assert 0 < len(again) <= len(original)
    for _ in range(len(again)):
        a, b = original.next_frame(), again.next_frame()
        assert a.stamp_s == b.stamp_s and a.pose == b.pose and np.array_equal(a.depth_m, b.depth_m)
    with pytest.raises(ValueError, match="record_dir must differ"):
        replace(options, record_dir=root / "recording")


def test_report_json_html_and_markdown(measured, tmp_path):
    _, loop, models, _ = measured
    host = load_profile("host")
    doc = build_report(host, [load_profile(p) for p in PROFILES], loop, models, "edge-explorer profile (test)")
    doc = json.loads(json.dumps(doc))  # what report.json holds
    host_section, coral = doc["profiles"]
    assert host_section["kind"] == "measured" and coral["kind"] == "estimate"
    assert all(not v["estimate"] for v in host_section["verdicts"] if v["unit"] == "ms")
    assert all(v["estimate"] for v in coral["verdicts"])
    assert {v["status"] for v in host_section["verdicts"]} <= {"PASS", "FAIL", "n/a"}
    policy = next(v for v in coral["verdicts"] if v["check"] == "policy p95")
    assert policy["status"] == "n/a" and "card.json is missing" in policy["note"]
    # the coral's predictor: no Edge TPU or TFLite artifact in this card → onnxruntime on the A72, fp32 ratio
    row = next(m for m in coral["models"] if m["model"] == "predictor")
    cpu_ratio = host.cpu.peak_fp32_gflops_per_core / 12.0  # the host's peak over the Coral board's A72
    assert row["engine"] == "onnxruntime-cpu (fp32)" and row["ratio"] == pytest.approx(cpu_ratio)
    assert row["note"].startswith("no Edge TPU artifact in the card")
    fuse = coral["stages"]["fuse"]["p95_ms"]
    assert fuse == pytest.approx(host_section["stages"]["fuse"]["p95_ms"] * cpu_ratio)
    assert next(m for m in doc["models"] if m["name"] == "policy")["present"] is False
    assert doc["models"][0]["macs"] > 0  # counted from the tiny graph

    write_html(tmp_path / "report.html", doc, loop.samples_ms)
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 3 and "ESTIMATE scaled from the host" in page
    assert "http://" not in page and "https://" not in page  # self-contained
    text = markdown_summary(doc)
    assert "## coral-usb (ESTIMATE scaled from the host)" in text and "(estimate)" in text
    assert (
        "Backend order: predictor: edgetpu → litert-cpu → onnxruntime-cpu; policy: litert-cpu → onnxruntime-cpu" in text
    )
    assert host_section["backend_orders"]["policy"] == ["litert-cpu", "onnxruntime-cpu"]
    assert "| policy | – | – | – | – | – | unavailable:" in text


def test_bad_arguments_are_one_line_errors(capsys, tmp_path):
    assert main(["profile", "--profile", "mars-rover", "--out", str(tmp_path)]) == 2
    assert "device profile 'mars-rover' not found" in capsys.readouterr().err
    assert main(["profile", "--backend", "tensorrt", "--out", str(tmp_path)]) == 2
    assert "--backend 'tensorrt': choose from" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n")
    assert main(["profile", "--profile", str(bad), "--out", str(tmp_path)]) == 2
    assert main(["profile", "--record", str(bad), "--out", str(tmp_path)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert not list(tmp_path.glob("report.*"))
