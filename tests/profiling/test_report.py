"""A short real run of the daemon's loop with a tiny ONNX predictor (no policy shipped) into the full report."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from edge_explorer.cli import main
from edge_explorer.profiling.device_profile import load_profile
from edge_explorer.profiling.loop import LoopOptions, measure_loop
from edge_explorer.profiling.models import bench_models
from edge_explorer.profiling.report import build_report, markdown_summary, write_html
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
    assert row["engine"] == "onnxruntime-cpu (fp32)" and row["ratio"] == pytest.approx(83.0 / 12.0)
    assert row["note"].startswith("no Edge TPU artifact in the card")
    fuse = coral["stages"]["fuse"]["p95_ms"]
    assert fuse == pytest.approx(host_section["stages"]["fuse"]["p95_ms"] * 83.0 / 12.0)
    assert next(m for m in doc["models"] if m["name"] == "policy")["present"] is False
    assert doc["models"][0]["macs"] > 0  # counted from the tiny graph

    write_html(tmp_path / "report.html", doc, loop.samples_ms)
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 3 and "ESTIMATE scaled from the host" in page
    assert "http://" not in page and "https://" not in page  # self-contained
    text = markdown_summary(doc)
    assert "## coral-usb (ESTIMATE scaled from the host)" in text and "(estimate)" in text
    assert "| policy | – | – | – | – | – | unavailable:" in text


def test_bad_arguments_are_one_line_errors(capsys, tmp_path):
    assert main(["profile", "--profile", "mars-rover", "--out", str(tmp_path)]) == 2
    assert "device profile 'mars-rover' not found" in capsys.readouterr().err
    assert main(["profile", "--backend", "tensorrt", "--out", str(tmp_path)]) == 2
    assert "--backend 'tensorrt': choose from" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n")
    assert main(["profile", "--profile", str(bad), "--out", str(tmp_path)]) == 2
    assert not list(tmp_path.glob("report.*"))
