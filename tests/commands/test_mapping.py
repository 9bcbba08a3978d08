import json

import numpy as np
import pytest

from edge_explorer.cli import main
from edge_explorer.commands.mapping import FLIGHT_HEIGHT_M, PATH_CLEARANCE_M, bench_trajectory
from edge_explorer.world.plan import save_plan_json
from edge_explorer.world.raster import clearance_m, rasterize
from tests.conftest import two_room_plan


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("plans") / "two-rooms.json"
    save_plan_json(two_room_plan(), path)
    return path


def test_trajectory_is_deterministic_and_stays_clear_of_obstacles() -> None:
    raster = rasterize(two_room_plan(), 0.05)
    poses = bench_trajectory(raster, 40)
    assert poses == bench_trajectory(raster, 40) and len(poses) == 40
    clear = clearance_m(raster)
    rows, cols = raster.grid.cell_of(np.array([p.x_m for p in poses]), np.array([p.y_m for p in poses]))
    assert np.all(clear[rows, cols] >= PATH_CLEARANCE_M - 0.1)  # smoothing may cut a corner by a few cm
    assert {p.z_m for p in poses} == {FLIGHT_HEIGHT_M}
    assert min(p.x_m for p in poses) < 1.5 and max(p.x_m for p in poses) > 2.5  # visits both rooms


def test_map_bench_reports_speed_and_accuracy(plan_file, tmp_path, capsys) -> None:
    out, png = tmp_path / "bench.json", tmp_path / "bench.png"
    assert (
        main(["map", "bench", "--frames", "12", "--plan", str(plan_file), "--json", str(out), "--png", str(png)]) == 0
    )
    report = json.loads(out.read_text())
    assert report["frames"] == 12 and report["resolutions_m"] == [0.05, 0.2]
    assert report["fuse_ms"]["median"] > 0 and report["points_per_s"] > 0 and report["render_ms"]["p95"] > 0
    for res in ("0.05", "0.20"):
        truth = report["truth_agreement"][res]
        assert truth["observed_interior_cells"] > 0.5 * truth["interior_cells"]
        assert truth["correct_fraction"] > 0.9
    assert "octomap" not in report
    assert png.stat().st_size > 10_000
    assert "fuse 0.05+0.20 m" in capsys.readouterr().out


def test_map_bench_vs_octomap_builds_the_same_maps(plan_file, tmp_path) -> None:
    pytest.importorskip("octomap")
    out = tmp_path / "bench.json"
    assert main(["map", "bench", "--frames", "6", "--plan", str(plan_file), "--json", str(out), "--vs-octomap"]) == 0
    octo = json.loads(out.read_text())["octomap"]
    assert octo["ms"]["median"] > 0 and octo["speed_ratio_median"] > 1
    for res in ("0.05", "0.20"):
        assert octo["agreement"][res]["cells_both_know"] > 0
        assert octo["agreement"][res]["agree_fraction"] >= 0.99


def test_map_bench_bad_plan_is_a_user_error(tmp_path, capsys) -> None:
    assert main(["map", "bench", "--frames", "3", "--plan", str(tmp_path / "missing.json")]) == 2
    assert "error" in capsys.readouterr().err
