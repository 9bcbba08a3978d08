"""The suite leaves the tree clean: the check that tests/conftest.py runs around the whole session works."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests.tree_state import new_entries, porcelain


def _git(root: Path, *args: str) -> None:
    subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True)


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    try:
        _git(tmp_path, "init", "-q")
    except (FileNotFoundError, subprocess.CalledProcessError):
        pytest.skip("git is not available")
    (tmp_path / ".gitignore").write_text("/runs/\nonnxruntime_profile_*.json\n")
    (tmp_path / "tracked.txt").write_text("a\n")
    _git(tmp_path, "add", ".gitignore", "tracked.txt")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "init")
    return tmp_path


def test_new_untracked_and_modified_files_are_reported(checkout: Path) -> None:
    before = porcelain(checkout)
    assert before == frozenset()
    (checkout / "tracked.txt").write_text("b\n")
    (checkout / "sub").mkdir()
    (checkout / "sub" / "stray.json").write_text("{}")
    assert new_entries(before, porcelain(checkout)) == [" M tracked.txt", "?? sub/stray.json"]


def test_source_edits_are_not_the_suites(checkout: Path) -> None:
    before = porcelain(checkout)
    (checkout / "module.py").write_text("x = 1\n")
    (checkout / "edge_explorer" / "learn" / "configs").mkdir(parents=True)
    (checkout / "edge_explorer" / "learn" / "configs" / "new.toml").write_text("")
    assert new_entries(before, porcelain(checkout)) == []


def test_ignored_folders_and_profiles_are_not_reported(checkout: Path) -> None:
    before = porcelain(checkout)
    (checkout / "runs").mkdir()
    (checkout / "runs" / "report.json").write_text("{}")
    (checkout / "onnxruntime_profile__2026-11-22_20-01-38_846.json").write_text("[]")
    assert new_entries(before, porcelain(checkout)) == []


def test_outside_a_checkout_there_is_nothing_to_compare(tmp_path: Path) -> None:
    assert porcelain(tmp_path / "not-a-checkout") is None
