"""The scripts kept in scripts/ still run: each Python script answers ``--help``, the shell scripts parse, and the
two that only read a benchmark JSON reproduce their figures from the one docs/bench/ keeps."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = REPO_ROOT / "scripts"
BENCH = REPO_ROOT / "docs" / "bench" / "policy_bundled.json"
PYTHON_SCRIPTS = sorted(p.name for p in SCRIPTS.glob("*.py"))
SHELL_SCRIPTS = sorted(p.name for p in SCRIPTS.glob("*.sh"))


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_the_scripts_are_there() -> None:
    assert PYTHON_SCRIPTS and SHELL_SCRIPTS


@pytest.mark.parametrize("name", PYTHON_SCRIPTS)
def test_python_script_answers_help(name: str, tmp_path: Path) -> None:
    result = _run([sys.executable, str(SCRIPTS / name), "--help"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "usage:" in result.stdout


@pytest.mark.parametrize("name", SHELL_SCRIPTS)
def test_shell_script_parses(name: str, tmp_path: Path) -> None:
    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("bash is not available")
    result = _run([bash, "-n", str(SCRIPTS / name)], cwd=tmp_path)
    assert result.returncode == 0, result.stderr


def test_paired_vs_pairs_a_bench_with_itself(tmp_path: Path) -> None:
    result = _run([sys.executable, str(SCRIPTS / "paired_vs.py"), str(BENCH), str(BENCH)], cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "drl+pred" in result.stdout and "diff +0.00 ± 0.00 m" in result.stdout


def test_within15_reads_the_bench(tmp_path: Path) -> None:
    result = _run(
        [sys.executable, str(SCRIPTS / "within15.py"), str(BENCH), "drl+pred", "--flights", "5"], cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip()
