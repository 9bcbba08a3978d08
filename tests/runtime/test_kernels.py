"""The flight's memory layout (docs/runtime/README.md, "Memory"): heavy imports only after the numba kernels are
loaded and LLVM's pages released; the start pose drawn without compiling; no kernel loaded after the release."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan

ROOT = Path(__file__).resolve().parents[2]
# What the flight imports after its kernels are loaded and LLVM's pages released (runtime/flight.py: fly).
HEAVY = ("numba", "llvmlite", "scipy", "cv2", "pymavlink", "ai_edge_litert", "onnxruntime", "matplotlib", "gymnasium")


def _python(script: str, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=240, env=environment)


def _llvm_rss_kb_script() -> str:
    return (
        "from pathlib import Path\n"
        "from edge_explorer.runtime.kernels import _mappings\n"
        "print('LLVM_KB', sum(m[3] for m in _mappings(Path('/proc/self/smaps').read_text(), 'libllvmlite')"
        " if 'w' not in m[2] and not m[4]))\n"
    )


def test_the_flight_entry_point_imports_nothing_heavy():
    """`edge-explorer run` up to fly(): no numba (LLVM), scipy, OpenCV, pymavlink, LiteRT, … yet — fly() imports
    them in its own order, the flight's kernels and LLVM's release first."""
    script = (
        "import sys\n"
        "import edge_explorer.cli, edge_explorer.commands.runtime\n"
        "import edge_explorer.runtime.flight, edge_explorer.runtime.kernels\n"
        f"print('HEAVY', sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r}))\n"
    )
    result = _python(script)
    assert result.returncode == 0, result.stderr
    assert "HEAVY []" in result.stdout


def test_llvm_pages_are_released_and_fault_back_when_needed():
    """The release unmaps LLVM's read-only pages; compiled kernels still run, and a new one still compiles."""
    script = (
        "import numba\n"
        "from edge_explorer.runtime.kernels import release_llvm_pages\n"
        "f = numba.njit(lambda x: x * 2 + 1)\n"
        "assert f(3) == 7\n"
        + _llvm_rss_kb_script()
        + "print('RELEASED_MB', release_llvm_pages())\n"
        + _llvm_rss_kb_script()
        + "assert f(4) == 9\n"
        "g = numba.njit(lambda x: x - 1.5)\n"
        "assert g(4.0) == 2.5\n"
        "print('OK')\n"
    )
    result = _python(script)
    assert result.returncode == 0, result.stderr
    before, after = (int(line.split()[1]) for line in result.stdout.splitlines() if line.startswith("LLVM_KB"))
    released = float(next(line.split()[1] for line in result.stdout.splitlines() if line.startswith("RELEASED_MB")))
    assert before > 10_000 and after < 2_000 and released * 1024 > 0.8 * before
    assert "OK" in result.stdout


@pytest.mark.slow
def test_the_start_pose_drawn_in_its_child_is_the_benchmarks():
    from edge_explorer.sim.flight import _start_pose
    from edge_explorer.sim.starts import start_pose
    from edge_explorer.world.catalog import load_building

    for plan, seed in (("A", 0), ("C", 7)):
        raster = load_building(plan)
        assert _start_pose(raster, seed) == tuple(float(v) for v in start_pose(raster, seed))


@pytest.mark.slow
def test_a_flight_loads_no_kernel_after_the_release(tmp_path):
    """The default configuration (the shipped models), from an empty numba cache: the compiler child fills it, the
    flight's process loads every kernel before the release and none after it (LLVM's pages are still released at
    the end), and the summary names the children's peak."""
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out = tmp_path / "out"
    args = ["run", "--plan", str(plan), "--out", str(out), "--time-limit-s", "6", "--no-return"]
    script = (
        "import sys\n"
        "from edge_explorer.cli import main\n"
        f"code = main({args + ['--models', str(ROOT / 'models')]!r})\n" + _llvm_rss_kb_script() + "sys.exit(code)\n"
    )
    result = _python(script, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    assert result.returncode == 0, result.stdout + result.stderr
    llvm_kb = int(next(line.split()[1] for line in result.stdout.splitlines() if line.startswith("LLVM_KB")))
    assert llvm_kb < 4_000, f"{llvm_kb} kB of LLVM's pages came back: a kernel was loaded after the release"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["collisions"] == 0 and summary["children_peak_rss_mb"] > 50


@pytest.mark.slow
def test_the_programs_peak_is_the_flights(tmp_path):
    """`python -m edge_explorer.cli run` as /usr/bin/time -v sees it (the kernel's maximum resident set over the
    process tree): no more than the flight's own peak or its children's. On a fresh install it was ~45 MB more when
    LLVM's destructors faulted its code back in at exit, after the flight (kernels.exit_without_native_teardown);
    in an older .venv, whose libraries sit in small page-cache folios, that spike stays under the flight's peak."""
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "edge_explorer.cli", "run", "--plan", str(plan), "--out", str(out)]
    command += ["--time-limit-s", "6", "--no-return", "--models", str(ROOT / "models")]
    # Like /usr/bin/time -v: a parent that only waits, then reads its children's maximum resident set.
    wrapper = (
        "import resource, subprocess, sys\n"
        f"run = subprocess.run({command!r}, capture_output=True, text=True)\n"
        "print(run.stdout + run.stderr)\n"
        "print('TREE_MAXRSS_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
        "sys.exit(run.returncode)\n"
    )
    result = _python(wrapper)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "summary.png").stat().st_size > 0 and "summary:" in result.stdout  # outputs and stdout complete
    tree_kb = int(next(line.split()[1] for line in result.stdout.splitlines() if line.startswith("TREE_MAXRSS_KB")))
    flight_kb = 1024 * max(summary["peak_rss_mb"], summary["children_peak_rss_mb"])
    assert tree_kb <= 1.03 * flight_kb, f"the program peaked at {tree_kb} kB, its flight at {flight_kb:.0f} kB"
