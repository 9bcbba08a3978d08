"""Shared tiny fixtures: a two-room plan small enough to reason about by hand; the suite leaves the tree clean."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from edge_explorer.world.plan import FloorPlan, Furniture, Rect
from tests.tree_state import new_entries, porcelain

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session", autouse=True)
def tree_stays_clean() -> Iterator[None]:
    """Tests write only into ignored folders (tmp_path, runs/): nothing new in ``git status`` after the session."""
    before = porcelain(REPO_ROOT)
    yield
    if before is None:
        return  # not a git checkout (an unpacked sdist): nothing to compare
    written = new_entries(before, porcelain(REPO_ROOT) or frozenset())
    assert not written, "the test session wrote into the tree outside ignored folders: " + ", ".join(written)


def two_room_plan(door: bool = True, name: str = "two-rooms") -> FloorPlan:
    """4 m × 3 m building, 0.1 m walls, split at x = 2 by a wall with a 1 m door; one tall and one low item."""
    walls = (
        Rect(0.0, 0.0, 4.0, 0.1),
        Rect(0.0, 2.9, 4.0, 3.0),
        Rect(0.0, 0.0, 0.1, 3.0),
        Rect(3.9, 0.0, 4.0, 3.0),
        Rect(1.95, 0.0, 2.05, 3.0),
    )
    doors = (Rect(1.95, 1.0, 2.05, 2.0),) if door else ()
    furniture = (Furniture(Rect(0.1, 2.4, 0.7, 2.9), 1.8), Furniture(Rect(2.8, 0.6, 3.4, 1.2), 0.75))
    return FloorPlan(name, ((0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)), walls, doors, furniture)


@pytest.fixture
def plan() -> FloorPlan:
    return two_room_plan()


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[None]:
    """A local Ray cluster of 2 CPUs on loopback for one test module (``--ray auto`` connects to it)."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[cluster]')")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()
