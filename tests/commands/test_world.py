import json

import pytest

from edge_explorer.cli import main
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan


def test_help_everywhere(capsys):
    for argv in (["--help"], ["plans", "--help"], ["plans", "generate", "--help"], ["plans", "show", "--help"]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 0
    assert "--count" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv",
    [
        ["plans", "generate", "--count", "-3", "--out", "x"],
        ["plans", "generate", "--count", "3"],
        ["nope"],
        ["plans", "generate", "--count", "3", "--out", "x", "--split", "1,2"],
    ],
)
def test_bad_arguments_exit_2_with_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("edge-explorer") and "error:" in err[-1]


def test_bad_plan_file_exits_2_naming_file(tmp_path, capsys):
    bad = tmp_path / "broken.json"
    bad.write_text('{"format": "edge-explorer/floorplan", "version": 1}')
    assert main(["plans", "check", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "broken.json" in err and "missing required key" in err


def test_disconnected_plan_is_rejected(tmp_path, capsys):
    path = tmp_path / "closed.json"
    save_plan_json(two_room_plan(door=False), path)
    assert main(["plans", "check", str(path)]) == 2
    assert "split into 2 regions" in capsys.readouterr().err


def test_check_and_show_report_figures(tmp_path, capsys):
    path = tmp_path / "ok.json"
    save_plan_json(two_room_plan(), path)
    out_json = tmp_path / "check.json"
    assert main(["plans", "check", str(path), "--json", str(out_json)]) == 0
    rows = json.loads(out_json.read_text())
    # 20 × 15 coarse cells, less the 4 outer corners and the 2 wall cells where the partition meets the outer walls:
    # their fine cells are wall behind wall faces, which no ray of the sensor reaches
    assert rows[0]["name"] == "two-rooms" and rows[0]["n_m"] == 20 * 15 - 6
    assert rows[0]["dropped_free_m2"] == 0 and rows[0]["dropped_wall_m2"] > 0
    assert main(["plans", "show", str(path), "--png", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_generate_command_reports_rate(tmp_path, capsys):
    out_json = tmp_path / "gen.json"
    argv = ["plans", "generate", "--count", "4", "--seed", "1", "--out", str(tmp_path / "ds"), "--workers", "1"]
    assert main(argv + ["--json", str(out_json)]) == 0
    figures = json.loads(out_json.read_text())
    assert figures["plans"] + len(figures["skipped"]) == 4 and figures["plans_per_s"] > 0
    assert "plans/s" in capsys.readouterr().out
