"""The arguments of one flight of ``edge-explorer run`` (:class:`RunOptions`): the type that the command line, the
flight (:mod:`edge_explorer.runtime.flight`), its summary and the acceptance bench share. Nothing here imports them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"


@dataclass(frozen=True)
class RunOptions:
    """One flight of ``edge-explorer run`` (the command's arguments)."""

    out_dir: Path
    planner: str = "auto"
    profile: str = "host"
    connect: str | None = None
    source: str = "sim"
    plan: str | None = "A"
    time_limit_s: float | None = None  # None: DaemonConfig's
    return_home: bool = True
    seed: int = 0
    run_index: int = 0  # the run's noise seed is the benchmark's run_seed(seed, plan, run_index)
    models_dir: Path = MODELS_DIR
    record_dir: Path | None = None
    autopilot: str = "px4"
    progress: bool = True
