"""The soak (``edge-explorer run --soak``): a few seconds of back-to-back flights of the tiny plan in one process."""

from __future__ import annotations

import argparse
import gc
import json

import pytest

from edge_explorer.cli import main
from edge_explorer.runtime.soak import parse_duration, rss_growth, soak_report
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan


def test_durations_parse_and_bad_ones_are_one_line_errors():
    assert parse_duration("30m") == 1800 and parse_duration("90s") == 90 and parse_duration("1.5h") == 5400
    assert parse_duration("12") == 12
    for bad in ("", "0m", "-5s", "30 minutes", "m", "nan"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_duration(bad)


def test_rss_growth_counts_from_the_first_sixth_of_the_soak():
    samples = [(0.0, 100.0, 0, 0), (5.0, 200.0, 0, 0), (10.0, 200.0, 0, 0), (30.0, 204.0, 0, 0)]
    assert rss_growth(samples, 30.0) == pytest.approx(0.02)  # the take-off's growth (100 → 200 MB) is not counted
    assert rss_growth(samples[:2], 30.0) is None  # one sample after the first sixth: no growth to measure


def test_the_verdict_needs_no_crash_no_collision_and_flat_rss():
    samples = [(t, 200.0, 150.0, 50.0) for t in (0.0, 10.0, 60.0)]
    flight = {"flight": 0, "start_s": 0.0, "decisions": 5, "holds": 1, "collisions": 0}
    assert soak_report([flight], samples, 60.0, 61.0)["passed"]
    assert not soak_report([{**flight, "collisions": 1}], samples, 60.0, 61.0)["passed"]
    assert not soak_report([flight, {"flight": 1, "start_s": 30.0, "crash": "boom"}], samples, 60.0, 61.0)["passed"]
    growing = [*samples, (61.0, 220.0, 170.0, 50.0)]
    assert not soak_report([flight], growing, 60.0, 61.0)["passed"]


def test_soak_rejects_a_real_autopilot(tmp_path, capsys):
    code = main(["run", "--soak", "1m", "--connect", "udpin:127.0.0.1:14550", "--source", "realsense"])
    assert code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("drop --connect, --source and --record")


@pytest.mark.slow
def test_a_short_soak_flies_flights_back_to_back_and_reports_them(tmp_path, capsys):
    gc.collect()  # daemons an earlier test left in reference cycles are not this soak's
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out = tmp_path / "soak"
    arguments = ["run", "--plan", str(plan), "--soak", "25s", "--time-limit-s", "2", "--no-return"]
    code = main([*arguments, "--out", str(out)])  # the shipped models: the goal policy flies
    report = json.loads((out / "soak.json").read_text())
    assert report["flights"] >= 2 and report["crashes"] == 0 and report["collisions"] == 0
    assert report["decisions"] == sum(f["decisions"] for f in report["per_flight"]) > 0
    assert len(report["samples"]) >= 2 and all(s["rss_mb"] > 0 for s in report["samples"])
    assert code == (0 if report["passed"] else 1)
    for k in range(report["flights"]):
        assert (out / f"flight{k:03d}" / "summary.json").is_file()
    assert (out / "soak.png").stat().st_size > 0
    assert "soak: " in capsys.readouterr().out
    from edge_explorer.runtime.daemon import Daemon

    # each flight is freed as it ends, not at the cyclic collector's next full pass (+31 MB a flight otherwise)
    assert not [o for o in gc.get_objects() if isinstance(o, Daemon)]
