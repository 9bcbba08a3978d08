"""map_units (edge_explorer.cluster): every unit once, whichever engine runs it, even when a worker dies."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError

DOOMED = 3  # the unit whose first worker dies


def square_or_die(unit: tuple[Path, int]) -> int:
    """k², except that the first process to run unit DOOMED while the marker exists removes it and dies."""
    marker, k = unit
    if k == DOOMED:
        try:
            marker.unlink()
        except FileNotFoundError:
            pass
        else:
            os._exit(1)  # a lost worker: no exception, no result, the process is gone
    return k * k


def units(tmp_path: Path, n: int = 8) -> list[tuple[Path, int]]:
    marker = tmp_path / "kill-once"
    marker.touch()
    return [(marker, k) for k in range(n)]


def assert_each_unit_once(results: list[tuple[int, int]], n: int = 8) -> None:
    assert sorted(k for k, _ in results) == list(range(n))  # none lost, none duplicated
    assert all(value == k * k for k, value in results)


def test_in_process_and_pool_give_every_unit(tmp_path):
    work = [(tmp_path / "no-marker", k) for k in range(5)]
    assert sorted(map_units(square_or_die, work)) == [(k, k * k) for k in range(5)]
    assert sorted(map_units(square_or_die, work, workers=2)) == [(k, k * k) for k in range(5)]


def test_pool_reruns_the_unit_of_a_killed_worker(tmp_path):
    work = units(tmp_path)
    results = list(map_units(square_or_die, work, workers=2))
    assert not work[0][0].exists()  # the worker did die
    assert_each_unit_once(results)


def always_dies(k: int) -> int:
    os._exit(1)


def test_pool_gives_up_after_its_retries():
    with pytest.raises(EdgeExplorerError, match="died 2 times"):
        list(map_units(always_dies, [1, 2], workers=2, max_retries=1))


def test_ray_reruns_the_unit_of_a_killed_worker(tmp_path, ray_cluster):
    work = units(tmp_path)
    results = list(map_units(square_or_die, work, ray="auto"))
    assert not work[0][0].exists()
    assert_each_unit_once(results)


def refuse_odd(k: int) -> int:
    if k % 2:
        raise EdgeExplorerError(f"unit {k} is odd")
    return k


def test_a_units_error_reaches_the_caller_as_itself(ray_cluster):
    for engine in ({"workers": 2, "start_method": "spawn"}, {"ray": "auto"}):  # spawn: no fork beside Ray
        with pytest.raises(EdgeExplorerError) as raised:
            list(map_units(refuse_odd, [0, 1, 2], **engine))
        assert type(raised.value) is EdgeExplorerError and str(raised.value) == "unit 1 is odd"


def test_an_unreachable_ray_address_is_a_one_line_error():
    pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[cluster]')")
    with pytest.raises(EdgeExplorerError, match="no Ray head answers there"):
        list(map_units(square_or_die, [(Path("x"), 0)], ray="127.0.0.1:1"))
    with pytest.raises(EdgeExplorerError, match="host:port"):
        list(map_units(square_or_die, [(Path("x"), 0)], ray="somewhere"))


RUNTIME_PATH = (
    "runtime",
    "backends",
    "mapping",
    "predict",
    "plan",
    "vehicle",
    "world",
    "sim",
    "cluster",
)  # docs/design.md §2


def test_core_and_daemon_never_import_ray_or_torch_distributed():
    """Every module of the runtime path (the daemon's), the cluster helpers and the whole CLI's parser."""
    code = f"""
import importlib, pkgutil, sys
import edge_explorer, edge_explorer.cli
for package in {RUNTIME_PATH!r}:
    root = importlib.import_module("edge_explorer." + package)
    for module in pkgutil.walk_packages(root.__path__, root.__name__ + "."):
        importlib.import_module(module.name)
edge_explorer.cli.build_parser()
print(sorted(n for n in sys.modules if n.split(".")[0] == "ray" or n.startswith("torch.distributed")))
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
