"""The package's layers (docs/design.md §2, ``[tool.importlinter]`` in pyproject.toml): the import-linter contract is
kept, and ``edge-explorer run`` with a real autopilot (``--connect``) loads nothing of the simulator, the benchmark or
the training code, nor torch or gymnasium."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan

ROOT = Path(__file__).resolve().parents[1]
OFF_DEVICE = ("edge_explorer.sim", "edge_explorer.bench", "edge_explorer.learn", "edge_explorer.export")


def test_the_layers_contract_is_kept() -> None:
    lint_imports = Path(sys.executable).parent / "lint-imports"
    if not lint_imports.exists():
        pytest.skip("import-linter is not installed (the dev extra)")
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [str(lint_imports), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300, env=environment
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 kept, 0 broken" in done.stdout


@pytest.mark.slow
def test_a_flight_with_a_real_autopilot_imports_no_simulator_and_no_training_code(tmp_path: Path) -> None:
    """`edge-explorer run --connect URL --source replay:DIR --plan P` up to the daemon (the flight's set-up: device
    profile, plan, numba kernels, models, MAVLink link, depth source), then the modules it loaded."""
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    script = f"""
import sys
from pathlib import Path

import numpy as np

from edge_explorer.runtime.depth_sources import DepthFrame, Recorder
from edge_explorer.vehicle.camera import DepthIntrinsics

intrinsics = DepthIntrinsics.d435()
with Recorder(Path({str(tmp_path / "recording")!r}), intrinsics) as recorder:
    recorder.write(DepthFrame(np.full(intrinsics.shape, 2.0, np.float32), 0.0, intrinsics))

import edge_explorer.runtime.daemon as daemon_module


class Built(Exception):
    pass


def daemon(*args, **kwargs):
    raise Built


daemon_module.Daemon = daemon
from edge_explorer.cli import main

try:
    main(["run", "--connect", "udpout:127.0.0.1:9", "--source", "replay:{tmp_path / "recording"}",
          "--plan", {str(plan)!r}, "--models", {str(tmp_path / "none")!r}, "--out", {str(tmp_path / "out")!r}])
except Built:
    print("BUILT")
print("MODULES", " ".join(sorted(sys.modules)))
"""
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=environment)
    assert done.returncode == 0, done.stderr
    assert "BUILT" in done.stdout, done.stdout + done.stderr
    modules = next(line for line in done.stdout.splitlines() if line.startswith("MODULES ")).split()[1:]
    assert "edge_explorer.runtime.flight" in modules and "edge_explorer.runtime.mavlink_link" in modules
    assert [m for m in modules if m.startswith(OFF_DEVICE)] == []
    assert [m for m in modules if m.split(".")[0] in ("torch", "gymnasium", "stable_baselines3", "tensorflow")] == []
