"""Summing up the exploration benchmark's records (edge_explorer.bench.summary)."""

import pytest

from edge_explorer.bench.summary import (
    correct_area_at_m2,
    failures,
    markdown_budgets,
    markdown_paired,
    markdown_table,
    mean_curves,
    paired_differences,
    path_at,
    summarize,
)


def fake_record(plan, method, run, path_at, collisions=0, steps=10):
    return {
        "spec": {"plan": plan, "method": method, "run": run},
        "ending": "goal",
        "steps": steps,
        "collisions": collisions,
        "final_coverage": 0.96,
        "final_correct_coverage": 0.9,
        "path_at_coverage_m": path_at,
        "path_at_correct_coverage_m": None,
        "planner_s": 0.01,
        "wall_s": 0.5,
        "curves": {"coverage": [0.1, 0.5, 0.96], "correct_coverage": [0.1, 0.4, 0.9], "path_length_m": [0, 1, 2]},
    }


def test_summary_is_table_one():
    records = [
        fake_record("A", "frontier", 0, 10.0),
        fake_record("A", "frontier", 1, 14.0, collisions=2),
        fake_record("A", "frontier", 2, None),
        fake_record("B", "frontier", 0, 20.0),
    ]
    summary = summarize(records, ["frontier"])
    a = summary["plans"]["A"]["frontier"]
    assert a["path_at_coverage_m"] == {"min": 10.0, "max": 14.0, "avg": 12.0, "std": 2.0}
    assert (a["reached_coverage"], a["runs"], a["collisions"]) == (2, 3, 2)
    assert a["success_rate"] == pytest.approx(1 / 3)  # run 1 collided, run 2 never reached 95 %
    assert summary["all"]["frontier"]["path_at_coverage_m"]["avg"] == pytest.approx(44 / 3)
    table = markdown_table(summary, ["frontier"])
    assert "| A | frontier | 10.0 / 14.0 / 12.0 / 2.0 | 2/3 |" in table and "all (2 plans)" in table
    assert "| 10 | 1.0 | 0 |" in table  # steps, planning 10 ms over 10 steps, a 0.5 s run
    assert [f["run"] for f in failures(records)] == [1, 2]


def test_paired_difference_compares_methods_building_by_building():
    records = [
        fake_record("A", "frontier", 0, 10.0),
        fake_record("A", "frontier", 1, 14.0),  # A: frontier 12.0 on average
        fake_record("A", "fuel", 0, 11.0),
        fake_record("B", "frontier", 0, 50.0),
        fake_record("B", "fuel", 0, 53.0),
        fake_record("C", "frontier", 0, 30.0),
        fake_record("C", "fuel", 0, None),  # never reached 95 %: C is not compared
    ]
    (paired,) = paired_differences(records, ["frontier", "fuel"])
    assert (paired["a"], paired["b"], paired["buildings"], paired["b_shorter"]) == ("frontier", "fuel", 2, 1)
    assert paired["mean_m"] == pytest.approx(1.0)  # (−1 + 3) / 2
    assert paired["stderr_m"] == pytest.approx(2.0)  # std (ddof 1) of (−1, 3) is 2√2, over √2
    assert paired["median_m"] == pytest.approx(1.0)
    assert "| fuel − frontier | +1.0 ± 2.0 | +1.0 | 2 | 1 |" in markdown_paired([paired])


def test_path_at_90_percent_correct_coverage_comes_from_the_curves():
    record = fake_record("A", "frontier", 0, 2.0)  # correct coverage 0.1, 0.4, 0.9 at 0, 1, 2 m
    assert path_at(record, "path_at_correct_90_m") == 2.0
    record["curves"]["correct_coverage"] = [0.1, 0.4, 0.89]
    assert path_at(record, "path_at_correct_90_m") is None
    assert path_at(record, "path_at_coverage_m") == 2.0
    records = [fake_record("A", "frontier", 0, 2.0), fake_record("A", "fuel", 0, 2.0)]
    records[1]["curves"]["correct_coverage"] = [0.1, 0.95, 0.95]
    summary = summarize(records, ["frontier", "fuel"])
    assert summary["plans"]["A"]["fuel"]["path_at_correct_90_m"]["avg"] == 1.0
    assert "| A | frontier | 2.0 / 2.0 / 2.0 / 0.0 | 1/1 | 2.0 / 2.0 / 2.0 / 0.0 | 1/1 |" in markdown_table(
        summary, ["frontier", "fuel"]
    )
    (paired,) = paired_differences(records, ["frontier", "fuel"], "path_at_correct_90_m")
    assert (paired["metric"], paired["mean_m"]) == ("path_at_correct_90_m", -1.0)
    assert "path at 90 % correct coverage" in markdown_paired([paired])


def test_mean_curves_hold_the_final_value():
    short = fake_record("A", "fuel", 0, 1.0)
    long = fake_record("A", "fuel", 1, 1.0)
    long["curves"] = {
        "coverage": [0.0, 0.2, 0.4, 0.6, 0.8],
        "correct_coverage": [0.0] * 5,
        "path_length_m": [0.0, 1.0, 2.0, 3.0, 4.0],
    }
    curves = mean_curves([short, long], step_m=1.0)
    assert curves["path_m"] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert curves["coverage"]["mean"] == pytest.approx([0.05, 0.35, 0.68, 0.78, 0.88])


def test_correct_area_at_a_budget_holds_the_map_flown_so_far():
    record = fake_record("A", "frontier", 0, 2.0)  # correct coverage 0.1, 0.4, 0.9 at 0, 1, 2 m
    assert correct_area_at_m2(record, 100.0) is None  # a record without the N_M area
    record["n_m_m2"] = 200.0
    record["curves"]["path_length_m"] = [0.0, 150.0, 300.0]
    assert correct_area_at_m2(record, 100.0) == pytest.approx(20.0)
    assert correct_area_at_m2(record, 200.0) == pytest.approx(80.0)
    assert correct_area_at_m2(record, 800.0) == pytest.approx(180.0)  # ended before the budget: its final map
    other = {**record, "spec": {"plan": "A", "method": "fuel", "run": 0}, "n_m_m2": 400.0}
    table = markdown_budgets(summarize([record, other], ["frontier", "fuel"]), ["frontier", "fuel"])
    assert "| frontier | 20 (1.00 ×) | 80 (1.00 ×) | 180 (1.00 ×) | 180 (1.00 ×) |" in table
    assert "| fuel | 40 (2.00 ×)" in table
