"""``edge-explorer sim bench`` and ``sim show``."""

import json

import pytest

from edge_explorer.cli import main
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan


@pytest.fixture
def plan_file(tmp_path):
    path = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), path)
    return path


def test_bench_reports_rate_and_stage_shares(plan_file, tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["sim", "bench", "--steps", "60", "--warmup", "5", "--plans", str(plan_file), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["steps"] == 60 and report["steps_per_s"] > 0 and report["plans"] == ["two-rooms"]
    assert set(report["stages"]) == {
        "dynamics",
        "sensor",
        "map_update",
        "metrics_reward",
        "observation",
        "reset",
        "other",
    }
    assert sum(s["share"] for s in report["stages"].values()) == pytest.approx(1.0)
    assert report["observation_shapes"] == {"high": [237, 237], "thres": [237, 237], "last_action": [6]}
    assert "env steps/s" in capsys.readouterr().out


@pytest.mark.parametrize("policy", ["scripted", "random"])
def test_show_draws_png_and_gif(plan_file, tmp_path, policy):
    png, gif = tmp_path / "ep.png", tmp_path / "ep.gif"
    argv = [
        "sim",
        "show",
        "--plan",
        str(plan_file),
        "--steps",
        "4",
        "--png",
        str(png),
        "--gif",
        str(gif),
        "--policy",
        policy,
    ]
    assert main(argv) == 0
    assert png.read_bytes()[:4] == b"\x89PNG" and gif.read_bytes()[:3] == b"GIF"


def test_bad_plan_is_a_one_line_error(tmp_path, capsys):
    assert main(["sim", "show", "--plan", str(tmp_path / "none.json"), "--steps", "3", "--png", "x.png"]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_:
        main(["sim", "bench", "--steps", "0"])
    assert exit_.value.code == 2
