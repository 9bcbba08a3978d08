"""`bench explore --ray`: the same records as the local process pool, in the same files."""

from __future__ import annotations

import json
from pathlib import Path

from edge_explorer.cli import main
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan

WALL_TIME_FIELDS = ("wall_s", "planner_s")


def sweep(plan: Path, out_dir: Path, *engine: str) -> dict[str, dict]:
    argv = ["bench", "explore", "--plans", str(plan), "--methods", "frontier,fuel", "--runs", "2"]
    assert main([*argv, "--max-steps", "25", "--seed", "3", "--out-dir", str(out_dir), *engine]) == 0
    return {
        path.name: {k: v for k, v in json.loads(path.read_text()).items() if k not in WALL_TIME_FIELDS}
        for path in sorted(out_dir.glob("*.json"))
    }


def test_ray_writes_the_pools_records(tmp_path, ray_cluster):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    pool = sweep(plan, tmp_path / "pool", "--workers", "2")
    ray = sweep(plan, tmp_path / "ray", "--ray", "auto")
    assert len(pool) == 4 and pool == ray


def test_an_unreachable_ray_head_is_a_one_line_error(tmp_path, capsys):
    assert main(["bench", "explore", "--plans", "A", "--runs", "1", "--ray", "127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ray 127.0.0.1:1" in err
