"""Predictor training data (learn/predictor_data.py): moments drawn over a flight's steps, and whole-floor shards."""

import dataclasses
import json

import numpy as np

from edge_explorer.learn import predictor_data
from edge_explorer.learn.predictor_data import FLOOR_SAMPLES, SampleConfig, collect_plan_samples, floor_jobs
from edge_explorer.learn.predictor_flights import FlightLimits, RandomGoalWalk
from edge_explorer.learn.predictor_shards import load_shards
from edge_explorer.world.catalog import plan_to_raster
from tests.conftest import two_room_plan


def test_moments_drawn_over_the_steps_are_recorded_where_coverage_levels_would_go_unreached(scene):
    """A 30-step flight sees part of the two rooms: most coverage levels up to 1 are never reached (the final map
    stands in for them, once), while moments drawn over its 30 steps are each recorded as the flight passes them."""
    limits = FlightLimits(max_steps=30)
    by_coverage = SampleConfig(samples_per_plan=8, limits=limits)
    by_step = dataclasses.replace(by_coverage, by_step=True)
    kept = collect_plan_samples(scene, [RandomGoalWalk()], np.random.default_rng(4), by_coverage)
    drawn = collect_plan_samples(scene, [RandomGoalWalk()], np.random.default_rng(4), by_step)
    assert kept[-1].coverage < 0.9 and len(kept) < 8
    assert len(drawn) > len(kept)
    areas = [s.observed_area_m2 for s in drawn]
    assert areas == sorted(areas) and areas[0] < areas[-1]
    again = collect_plan_samples(scene, [RandomGoalWalk()], np.random.default_rng(4), by_step)
    assert all(np.array_equal(a.observed_low, b.observed_low) for a, b in zip(drawn, again, strict=True))


def test_floor_jobs_cover_the_floors_of_a_split_one_shard_each(tmp_path):
    jobs = floor_jobs(tmp_path, "train", 3, 1, FLOOR_SAMPLES)
    assert [(j.first, j.stop, j.plan_shard) for j in jobs] == [(0, 1, None), (1, 2, None), (2, 3, None)]
    assert [j.out.name for j in jobs] == ["shard-00000.npz", "shard-00001.npz", "shard-00002.npz"]


def test_whole_floor_shards_are_recorded_from_the_floor_split_and_resume(tmp_path, monkeypatch):
    """The whole floors come from the catalog's floor split (a tiny stand-in here: generating and cutting a real
    floor takes minutes); the shard holds the floor's samples, and a second call finds it done."""
    requested = []

    def tiny_floors(split, first, stop):
        requested.append((split, first, stop))
        return [dataclasses.replace(plan_to_raster(two_room_plan()), name=f"floor-{split}-{first:05d}")]

    monkeypatch.setattr("edge_explorer.world.catalog.floor_rasters", tiny_floors)
    config = dataclasses.replace(FLOOR_SAMPLES, samples_per_plan=4, limits=FlightLimits(max_steps=40))
    report = predictor_data.generate_predictor_data(
        tmp_path / "unused", tmp_path / "out", {"val": 1}, config, 1, floors=True
    )
    assert requested == [("val", 0, 1)] and report.plans == 1 and 1 <= report.samples <= 4
    marker = json.loads((tmp_path / "out" / "val" / "shard-00000.json").read_text())
    assert marker["source"] == "floors-val" and marker["samples"] == report.samples
    store = load_shards([tmp_path / "out" / "val" / "shard-00000.npz"])
    assert len(store) == report.samples and store.plan_names == ["floor-val-00000"]
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["plans_dir"] == "floors" and manifest["config"]["by_step"] is True
    again = predictor_data.generate_predictor_data(
        tmp_path / "unused", tmp_path / "out", {"val": 1}, config, 1, floors=True
    )
    assert again.shards_done_before == 1 and again.plans == 0
