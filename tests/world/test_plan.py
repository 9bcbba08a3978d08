import json

import pytest

from edge_explorer.errors import PlanError
from edge_explorer.world.plan import FloorPlan, load_plan_json, save_plan_json
from tests.conftest import two_room_plan


def test_json_round_trip(tmp_path, plan):
    path = tmp_path / "p.json"
    save_plan_json(plan, path)
    assert load_plan_json(path) == plan


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("walls"), "missing required key 'walls'"),
        (lambda d: d.update(format="svg"), "'format' must be"),
        (lambda d: d.update(colour="red"), "unknown key(s) ['colour']"),
        (lambda d: d["walls"].append([1, 1, 0, 2]), "x_min < x_max"),
        (lambda d: d["walls"].append([1, 1, "a", 2]), "finite numbers"),
        (lambda d: d["doors"].__setitem__(0, [1.95, 1.0, 2.05, 1.5]), "doors must be at least 0.8 m"),
        (lambda d: d["doors"].append([10, 10, 11, 10.1]), "does not cross any wall"),
        (lambda d: d["outline"].__setitem__(1, [4.0, 0.5]), "not axis-aligned"),
        (lambda d: d["furniture"].append([1, 1, 1.5, 1.5, 9.0]), "height 9.0 m"),
    ],
)
def test_bad_plans_name_the_problem(tmp_path, plan, mutate, message):
    data = plan.to_dict()
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(PlanError) as err:
        load_plan_json(path)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_too_large_footprint_is_rejected():
    data = two_room_plan().to_dict()
    data["outline"] = [[0, 0], [22, 0], [22, 3], [0, 3]]
    with pytest.raises(PlanError, match="exceeds the 21 m × 11 m envelope"):
        FloorPlan.from_dict(data, "big")


def test_malformed_json_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{ nope")
    with pytest.raises(PlanError, match="not valid JSON"):
        load_plan_json(bad)
    with pytest.raises(PlanError, match="cannot read plan file"):
        load_plan_json(tmp_path / "missing.json")
