"""Whole office floors: determinism, size, validity and connectivity, their own splits, the catalog and the sheet."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from edge_explorer.cli import main
from edge_explorer.world.catalog import load_buildings_with_space
from edge_explorer.world.dataset import plan_seed
from edge_explorer.world.floor_layouts import SHAPES, FloorConfig
from edge_explorer.world.floors import (
    FLOOR_SPLIT_SIZES,
    floor_name,
    floor_seed,
    generate_floor,
    generate_floor_and_raster,
    resolve_floor_reference,
)
from edge_explorer.world.plan import FloorPlan, validate_plan
from edge_explorer.world.raster import check_connected

SMALL = FloorConfig(length_m=(40.0, 60.0), wing_length_m=(10.0, 20.0))
SMALL_FLOOR = "floor-test-00012"  # a 68 × 27 m L, 1,100 m² free: the smallest floor of the test split, quickest to cut


@cache
def small(seed: int) -> FloorPlan:
    return generate_floor(seed, f"small-{seed}", SMALL)


def test_same_seed_same_floor_and_different_seeds_differ():
    a, b = small(3).to_dict(), generate_floor(3, "small-3", SMALL).to_dict()
    assert a == b
    assert small(4).to_dict() != a


@pytest.mark.parametrize("seed", range(4))
def test_small_floors_are_valid_connected_and_sized(seed):
    plan, raster = generate_floor_and_raster(seed, "f", SMALL)
    validate_plan(plan)
    check_connected(raster, 0.25)
    b = plan.bounds()
    assert 40.0 <= max(b.width_m, b.height_m) <= 200.0
    assert plan.meta["family"] == "floor" and plan.meta["shape"] in SHAPES and plan.meta["seed"] == seed
    assert plan.meta["offices"] > 0 and plan.meta["rooms"] >= plan.meta["offices"]
    for door in plan.doors:
        assert 0.8 - 1e-9 <= max(door.width_m, door.height_m) <= 1.2 + 1e-9
    coords = [v for r in plan.walls + plan.doors for v in r.as_list()]
    assert np.allclose(np.round(np.array(coords) / 0.05) * 0.05, coords, atol=1e-9)


def test_floor_of_the_split_is_large_and_reproducible():
    plan = resolve_floor_reference("floor-test-00001")[0]
    assert plan.name == "floor-test-00001"
    assert plan.to_dict() == generate_floor(floor_seed(0, "test", 1), "floor-test-00001").to_dict()
    b = plan.bounds()
    assert 40.0 <= max(b.width_m, b.height_m) <= 200.0 and plan.meta["cores"] >= 1


def test_splits_are_disjoint_and_apart_from_the_plan_dataset():
    seeds = {s: {floor_seed(0, s, k) for k in range(200)} for s in ("train", "val", "test")}
    assert all(len(v) == 200 for v in seeds.values())
    assert not (seeds["train"] & seeds["val"] or seeds["train"] & seeds["test"] or seeds["val"] & seeds["test"])
    plans = {plan_seed(0, s, k) for s in ("train", "val", "test") for k in range(200)}
    assert not plans & set().union(*seeds.values())
    assert FLOOR_SPLIT_SIZES["test"] >= 30 and floor_name("test", 3) == "floor-test-00003"


def test_references():
    assert resolve_floor_reference("test") is None and resolve_floor_reference("A") is None
    assert resolve_floor_reference("floor-nope-00001") is None
    with pytest.raises(Exception, match="split"):
        floor_seed(0, "nope", 1)


def test_catalog_loads_one_floor_by_name():
    ((raster, space),) = load_buildings_with_space(SMALL_FLOOR)
    assert raster.name == SMALL_FLOOR and space.reachable.sum() * 0.05**2 > 200.0


def test_sheet_draws_floors(tmp_path, capsys):
    png = tmp_path / "floors.png"
    assert main(["plans", "sheet", "--plans", f"{SMALL_FLOOR},floor-val-00000", "--png", str(png)]) == 0
    assert png.stat().st_size > 1000 and "2 plans" in capsys.readouterr().out
