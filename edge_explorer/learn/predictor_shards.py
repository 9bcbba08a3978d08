"""The on-disk format of the map predictor's training samples: ``.npz`` shards and loading them into memory.

A :class:`Sample` is one partial map recorded in a flight (:mod:`edge_explorer.learn.predictor_data`): the observed
low-res map (0.20 m, in the plan's map frame), the robot's low-res cell, the observed area and the coverage; the truth
is stored once per plan. Shards are ``.npz`` files (plain arrays, no pickles, read with ``allow_pickle=False``); the
generator writes a ``.json`` marker beside each shard last, so :func:`shard_paths` lists only finished ones.
:func:`load_shards` reads shards into one :class:`SampleStore`. A sample is about 7 kB in memory.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.predictor_flights import Scene
from edge_explorer.world.grid import CELL_DTYPE

SHARD_FORMAT = "edge-explorer/predictor-samples"
SHARD_VERSION = 1


@dataclass(frozen=True)
class Sample:
    observed_low: np.ndarray  # int8 codes on the plan's 0.20 m grid
    robot_cell: tuple[int, int]  # (row, col) on that grid
    observed_area_m2: float
    coverage: float
    explorer: int  # index into the explorers of the run


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def write_shard(path: Path, scenes: Sequence[Scene], samples: Sequence[Sequence[Sample]]) -> None:
    """One ``.npz`` shard: per plan its name and 0.20 m truth, per sample its map, robot cell, area and coverage."""
    shapes = np.array([s.truth_low.shape for s in scenes], dtype=np.int32).reshape(-1, 2)
    flat = [x for per_plan in samples for x in per_plan]
    _write_npz(
        path,
        {
            "plan_names": np.array([s.name for s in scenes], dtype=str),
            "truth_shapes": shapes,
            "truth": np.concatenate([s.truth_low.ravel() for s in scenes] or [np.zeros(0, CELL_DTYPE)]),
            "sample_plan": np.array([i for i, per in enumerate(samples) for _ in per], dtype=np.int32),
            "observed": np.concatenate([x.observed_low.ravel() for x in flat] or [np.zeros(0, CELL_DTYPE)]),
            "robot_cells": np.array([x.robot_cell for x in flat], dtype=np.int32).reshape(-1, 2),
            "observed_area_m2": np.array([x.observed_area_m2 for x in flat], dtype=np.float32),
            "coverage": np.array([x.coverage for x in flat], dtype=np.float32),
            "explorer": np.array([x.explorer for x in flat], dtype=np.int16),
        },
    )


@dataclass(frozen=True)
class SampleStore:
    """Samples of one or more shards in memory: a flat int8 buffer per kind, indexed by offsets."""

    truth: list[np.ndarray]  # per plan, int8 (rows, cols)
    plan_names: list[str]
    sample_plan: np.ndarray  # (S,) index into truth
    observed: list[np.ndarray]  # per sample, int8 (rows, cols) of its plan
    robot_cells: np.ndarray  # (S, 2)
    observed_area_m2: np.ndarray  # (S,)
    coverage: np.ndarray  # (S,)

    def __len__(self) -> int:
        return len(self.observed)


def load_shards(paths: Sequence[Path]) -> SampleStore:
    """Read ``.npz`` shards (``allow_pickle=False``) into one :class:`SampleStore`."""
    truth: list[np.ndarray] = []
    names: list[str] = []
    sample_plan, observed, cells, areas, coverage = [], [], [], [], []
    for path in paths:
        with np.load(path, allow_pickle=False) as z:
            shapes = z["truth_shapes"]
            sizes = shapes.prod(axis=1)
            plan_truth = np.split(z["truth"], np.cumsum(sizes)[:-1]) if len(sizes) else []
            first = len(truth)
            truth += [t.reshape(shape) for t, shape in zip(plan_truth, shapes, strict=True)]
            names += [str(n) for n in z["plan_names"]]
            plans = z["sample_plan"]
            sample_sizes = sizes[plans]
            flat = np.split(z["observed"], np.cumsum(sample_sizes)[:-1]) if len(plans) else []
            observed += [o.reshape(shapes[p]) for o, p in zip(flat, plans, strict=True)]
            sample_plan.append(plans + first)
            cells.append(z["robot_cells"])
            areas.append(z["observed_area_m2"])
            coverage.append(z["coverage"])
    if not observed:
        raise EdgeExplorerError(f"no predictor samples in {[str(p) for p in paths]}; generate them first")
    return SampleStore(
        truth,
        names,
        np.concatenate(sample_plan),
        observed,
        np.concatenate(cells),
        np.concatenate(areas),
        np.concatenate(coverage),
    )


def shard_paths(folder: str | Path) -> list[Path]:
    """The finished shards of a folder (those whose marker exists), sorted."""
    folder = Path(folder)
    paths = sorted(p for p in folder.glob("shard-*.npz") if p.with_suffix(".json").exists())
    if not paths:
        raise EdgeExplorerError(f"{folder}: no finished predictor shards (shard-*.npz with a .json marker)")
    return paths
