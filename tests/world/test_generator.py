"""The plan generator: determinism, the dataset's rules on a sample of seeds, and the bundled buildings A–D."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest
from scipy import ndimage

import edge_explorer.world.generator as generator
from edge_explorer.errors import PlanError
from edge_explorer.world.generator import STYLES, generate_plan, style_of_seed
from edge_explorer.world.plan import MAX_FOOTPRINT_M, FloorPlan, load_plan_json, validate_plan
from edge_explorer.world.raster import check_connected, rasterize

BUNDLED = {"A": "corridor", "B": "hall", "C": "lshape", "D": "internal"}
SAMPLE = [(style, seed) for style in STYLES for seed in range(10)]


@cache
def sample_plan(style: str, seed: int) -> FloorPlan:
    return generate_plan(seed, f"{style}-{seed}", style)


def bundled_path(name: str):
    from importlib import resources

    return resources.files("edge_explorer") / "data" / "plans" / f"{name}.json"


def regions(plan: FloorPlan) -> tuple[list[np.ndarray], np.ndarray]:
    """Free space of each room / corridor / hall (doors closed), and the mask of cells outside the building."""
    raster = rasterize(dataclasses.replace(plan, doors=()), 0.05)
    labels, n = ndimage.label(raster.interior & ~raster.occupied)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    big = [k for k in range(1, n + 1) if sizes[k] * 0.05**2 >= 3.0]  # tall furniture can cut off slivers
    return [labels == k for k in big], ~raster.interior


def test_same_seed_same_plan_and_different_seeds_differ():
    a, b = generate_plan(7, "x"), generate_plan(7, "x")
    assert a.to_dict() == b.to_dict()
    assert generate_plan(8, "x").to_dict() != a.to_dict()
    assert generate_plan(7, "x", "hall").to_dict() == generate_plan(7, "x", "hall").to_dict()


def test_meta_reproduces_the_plan_and_styles_are_mixed():
    plan = generate_plan(123, "p")
    assert plan.meta == {"style": style_of_seed(123), "seed": 123, "rooms": plan.meta["rooms"], "generator": 1}
    again = generate_plan(plan.meta["seed"], "p", plan.meta["style"])
    assert again.to_dict() == plan.to_dict()
    drawn = [style_of_seed(s) for s in range(200)]
    assert all(drawn.count(s) > 30 for s in STYLES)


def test_bad_arguments():
    with pytest.raises(ValueError, match="style"):
        generate_plan(1, "x", "castle")
    with pytest.raises(ValueError, match="seed"):
        generate_plan(-1, "x")


@pytest.mark.parametrize("style,seed", SAMPLE)
def test_sample_obeys_the_dataset_rules(style, seed):
    plan = sample_plan(style, seed)
    validate_plan(plan)
    check_connected(rasterize(plan, 0.05), 0.25)
    b = plan.bounds()
    assert max(b.width_m, b.height_m) <= MAX_FOOTPRINT_M[0] and min(b.width_m, b.height_m) <= MAX_FOOTPRINT_M[1]
    assert plan.meta["style"] == style and 3 <= plan.meta["rooms"] <= 14
    for door in plan.doors:
        assert 0.8 - 1e-9 <= max(door.width_m, door.height_m) <= 1.2 + 1e-9
    for wall in plan.walls:
        assert 0.1 - 1e-9 <= min(wall.width_m, wall.height_m) <= 0.2 + 1e-9
    coords = [v for r in plan.walls + plan.doors for v in r.as_list()] + [v for p in plan.outline for v in p]
    assert np.allclose(np.round(np.array(coords) / 0.05) * 0.05, coords, atol=1e-9)
    # furniture never stands in a doorway or in the 0.6 m in front of it (on either side of the wall)
    for door in plan.doors:
        across_x = door.width_m < door.height_m  # a door in a wall along y: its front is along x
        dx, dy = (0.6, 0.0) if across_x else (0.0, 0.6)
        front = dataclasses.replace(
            door,
            x_min_m=door.x_min_m - dx,
            y_min_m=door.y_min_m - dy,
            x_max_m=door.x_max_m + dx,
            y_max_m=door.y_max_m + dy,
        )
        assert not any(item.rect.overlaps(front) for item in plan.furniture)
    # most rooms touch the outside wall; the "internal" style always has a block of rooms that do not, the
    # others at most the corridor / hall and a room in the inner corner of an L
    spaces, outside = regions(plan)
    assert len(spaces) >= plan.meta["rooms"]
    near_outside = ndimage.binary_dilation(outside, iterations=8)
    inner = sum(not (s & near_outside).any() for s in spaces)
    assert inner <= len(spaces) / 2
    assert inner >= 1 if style == "internal" else inner <= 2
    if style == "lshape":
        assert len(plan.outline) > 4


def test_sample_is_varied():
    plans = [sample_plan(style, seed) for style, seed in SAMPLE]
    assert len({p.meta["rooms"] for p in plans}) >= 6
    assert len({round(max(p.bounds().width_m, p.bounds().height_m)) for p in plans}) >= 5
    assert any(len(p.outline) > 4 for p in plans if p.meta["style"] != "lshape")  # cut corners elsewhere too
    tall = sum(f.is_tall for p in plans for f in p.furniture)
    low = sum(not f.is_tall for p in plans for f in p.furniture)
    assert tall > 40 and low > 40


def test_seed_that_never_validates_raises_plan_error_naming_it(monkeypatch):
    def always_split(raster, robot_radius_m=0.25, source=None):
        raise PlanError("split")

    monkeypatch.setattr(generator, "check_connected", always_split)
    with pytest.raises(PlanError, match="seed 5: "):
        generate_plan(5, "x", "corridor")


@pytest.mark.parametrize("name", sorted(BUNDLED))
def test_bundled_buildings(name):
    plan = load_plan_json(bundled_path(name))
    check_connected(rasterize(plan, 0.05), 0.25)
    assert plan.name == name and plan.meta["style"] == BUNDLED[name]
    b = plan.bounds()
    assert max(b.width_m, b.height_m) >= 15.0 and 5 <= plan.meta["rooms"] <= 12
    again = generate_plan(plan.meta["seed"], name, plan.meta["style"])
    assert again.to_dict() == plan.to_dict()
