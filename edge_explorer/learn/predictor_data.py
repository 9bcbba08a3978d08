"""Training data for the map predictor: partial maps recorded while exploring floor plans, with their ground truth.

Flights
-------
:func:`fly` explores one plan with the planar sensor (DESIGN.md §6, noise on): an :class:`Explorer` proposes sensor
poses, each pose is scanned into the two-level :class:`~edge_explorer.mapping.observed.ObservedMaps`, and every step
yields the observed-only coverage. The evaluation (:mod:`edge_explorer.learn.eval_predictor`) flies the same way.

An :class:`Explorer` is anything with a ``name`` and a ``poses(scene, maps, start, rng)`` generator that yields the
next pose after the caller has folded the previous scan into ``maps``, so it can decide from the growing map. The
mix that records the training data (:data:`DEFAULT_EXPLORERS`, one drawn per plan):

* :class:`RandomGoalWalk` with ``greedy_prob`` 0.8 and 0.2 — shortest paths through the true configuration space
  to random goals, facing the motion with jitter, a partial spin at each goal; the greedy walk prefers goals near
  unexplored parts of the building and reaches high coverage, the other lingers. (Goals only *visible* from the
  current position, a straight-segment walk, rarely find the doors: it stalls in the first rooms.)
* :class:`PlannerExplorer` — the benchmark's Nearest Frontier and FUEL-style planners (:mod:`edge_explorer.plan`)
  flying the six actions with the action table's dynamics, so the predictor sees the partial maps it will see in
  ``frontier+pred`` and ``fuel+pred``. Other planners (the learned policy) join the same way.

``SampleConfig.noise_free_fraction`` of the flights scan with a noise-free sensor, the rest with the training
noise (DESIGN.md §6), so the predictor sees both kinds of maps.

Samples and shards
------------------
Per plan, :func:`collect_plan_samples` draws coverage levels uniformly in [``min_coverage``, 1] and records the
observed low-res map (0.20 m, in the plan's map frame) the first time each level is reached, with the robot's
low-res cell and the observed area; the truth is stored once per plan. Shards are ``.npz`` files (plain arrays, no
pickles) written by :func:`generate_predictor_data` in parallel, resumably (a ``.json`` marker is written last),
from the plan shards of :mod:`edge_explorer.world.dataset`: ``train`` from the train split, ``val`` from val.
A sample is about 7 kB in memory.

:class:`PredictorDataset` turns a sample into network tensors: a random symmetry of the plan (the 8 flips and
90° rotations — an axis-aligned building stays a valid building) applied in the map frame, then the ego shift
:func:`~edge_explorer.mapping.ego.pad_shift` (robot at (128, 128)) and the encoding of
:mod:`edge_explorer.predict.encoding`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from numba import njit

from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS, pad_shift
from edge_explorer.mapping.metrics import map_metrics
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.predict.encoding import encode_windows, loss_weights, occupancy_target
from edge_explorer.sim import dynamics
from edge_explorer.sim.dynamics import wrap_angle_rad
from edge_explorer.sim.sensor import SensorConfig, scan
from edge_explorer.world.grid import CELL_DTYPE, LOW_RES_M, UNKNOWN, GridSpec
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, configuration_space

Pose = tuple[float, float, float]  # x_m, y_m, yaw_rad in the plan's map frame
SHARD_FORMAT = "edge-explorer/predictor-samples"
SHARD_VERSION = 1


# ---- one building, as the flights see it ------------------------------------------------------------------------
@dataclass(frozen=True)
class Scene:
    """The ground truth of one plan, derived once: what the sensor sees, where the robot may be, the 0.20 m truth."""

    name: str
    grid: GridSpec  # 0.05 m
    occupied: np.ndarray  # bool on grid: what the sensor sees
    blocked: np.ndarray  # bool on grid: where the robot's centre may not be (outside the configuration space)
    low_grid: GridSpec  # 0.20 m, same origin
    truth_low: np.ndarray  # int8 codes on low_grid: OCCUPIED / FREE inside, UNKNOWN outside the building
    interior_low: np.ndarray  # bool on low_grid

    @classmethod
    def from_raster(cls, raster: PlanRaster, robot_radius_m: float = ROBOT_RADIUS_M) -> Scene:
        low = raster.coarsened(LOW_RES_M)
        return cls(
            name=raster.name,
            grid=raster.grid,
            occupied=np.ascontiguousarray(raster.occupied),
            blocked=~configuration_space(raster, robot_radius_m),
            low_grid=low.grid,
            truth_low=low.truth_codes(),
            interior_low=low.interior,
        )

    def random_start(self, rng: np.random.Generator) -> Pose:
        """A uniform pose of the configuration space with a uniform heading."""
        free = np.flatnonzero(~self.blocked)
        if free.size == 0:
            raise EdgeExplorerError(f"{self.name}: no cell of the configuration space to start from")
        row, col = divmod(int(free[rng.integers(free.size)]), self.grid.shape[1])
        x0, y0 = self.grid.origin_xy
        res = self.grid.resolution_m
        return x0 + (col + rng.random()) * res, y0 + (row + rng.random()) * res, float(rng.uniform(-math.pi, math.pi))

    def low_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """(row, col) of the 0.20 m cell holding (x_m, y_m)."""
        row, col = self.low_grid.cell_of(x_m, y_m)
        return int(row), int(col)


# ---- explorers ---------------------------------------------------------------------------------------------------
class Explorer(Protocol):
    """Proposes sensor poses; ``maps`` holds every scan up to the last pose yielded."""

    @property
    def name(self) -> str: ...

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]: ...


@njit(cache=True)
def _bfs_parents(blocked, start):
    """Breadth-first search over the 8-connected unblocked cells from flat index ``start``: each reached cell's
    predecessor (the start's is itself), −1 where unreachable."""
    n_rows, n_cols = blocked.shape
    parent = np.full(blocked.size, -1, np.int64)
    queue = np.empty(blocked.size, np.int64)
    parent[start] = start
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        cell = queue[head]
        head += 1
        row, col = cell // n_cols, cell % n_cols
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                r, c = row + dr, col + dc
                if 0 <= r < n_rows and 0 <= c < n_cols and not blocked[r, c] and parent[r * n_cols + c] < 0:
                    parent[r * n_cols + c] = cell
                    queue[tail] = r * n_cols + c
                    tail += 1
    return parent


@dataclass(frozen=True)
class RandomGoalWalk:
    """Flights along shortest paths of the true configuration space to random goals; see the module docstring.

    Each goal is one of ``candidates`` random reachable cells. With probability ``greedy_prob`` the candidate with
    the most unknown interior cells within ``sensor_range_m`` wins (a frontier-seeking walk), otherwise the first
    (a uniform walk). The walk scans every ``step_m`` along the path, facing the motion ± Gaussian
    ``heading_jitter_rad``; at the goal it turns on the spot (30° per scan) for a uniform 0–``max_spin_scans`` scans.
    The path uses the ground truth (the collector knows the plan); what it records is only what the sensor saw.
    """

    greedy_prob: float = 0.7
    step_m: float = 0.5
    heading_jitter_rad: float = 0.3
    candidates: int = 24
    max_spin_scans: int = 6
    sensor_range_m: float = 4.5

    @property
    def name(self) -> str:
        return f"random-goal(greedy={self.greedy_prob:g})"

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]:
        x, y, yaw = start
        grid = scene.grid
        stride = max(1, round(self.step_m / grid.resolution_m))
        while True:
            row, col = (int(v) for v in grid.cell_of(x, y))
            parent = _bfs_parents(scene.blocked, row * grid.shape[1] + col)
            path = self._path_to_goal(scene, maps, parent, rng)
            for k in range(stride, len(path) + stride - 1, stride):
                r, c = divmod(int(path[min(k, len(path) - 1)]), grid.shape[1])
                nx, ny = (float(v) for v in grid.center_of(r, c))
                heading = math.atan2(ny - y, nx - x)
                x, y = nx, ny
                yaw = wrap_angle_rad(heading + rng.normal(0.0, self.heading_jitter_rad))
                yield x, y, yaw
            turn = math.radians(30) * (1 if rng.random() < 0.5 else -1)
            for _ in range(int(rng.integers(self.max_spin_scans + 1)) if len(path) > 1 else 12):
                yaw = wrap_angle_rad(yaw + turn)
                yield x, y, yaw

    def _path_to_goal(
        self, scene: Scene, maps: ObservedMaps, parent: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Flat cell indices from the robot's cell to the chosen goal (just the robot's cell if none is reachable)."""
        reachable = np.flatnonzero(parent >= 0)
        goals = reachable[rng.integers(reachable.size, size=self.candidates)]
        goal = int(goals[0])
        if rng.random() < self.greedy_prob:
            unknown = np.cumsum(np.cumsum((maps.low == UNKNOWN) & scene.interior_low, 0), 1)
            radius = int(round(self.sensor_range_m / maps.low_grid.resolution_m))
            factor = maps.factor
            cols = scene.grid.shape[1]
            scores = [_box_sum(unknown, (g // cols) // factor, (g % cols) // factor, radius) for g in goals]
            goal = int(goals[int(np.argmax(scores))])
        path = [goal]
        while parent[path[-1]] != path[-1]:
            path.append(int(parent[path[-1]]))
        return np.array(path[::-1], dtype=np.int64)


@dataclass(frozen=True)
class PlannerExplorer:
    """A benchmark planner of :mod:`edge_explorer.plan` (``frontier``, ``fuel``) flown with the action dynamics.

    Each step the planner picks one of the six actions from the observed maps; the pose follows the shipped action
    table with its motion noise, as in :class:`~edge_explorer.sim.env.ExplorationEnv`. A motion that would leave the
    configuration space is not executed (the vehicle stops: its next step starts as after hover).
    """

    planner: str = "frontier"

    @property
    def name(self) -> str:
        return self.planner

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]:
        from edge_explorer.plan.baselines import make_planner

        table = dynamics.load_action_table()
        planner = make_planner(self.planner, table)
        planner.reset()
        pose, previous = start, int(dynamics.Action.HOVER)
        while (action := planner.act(maps, pose, previous)) is not None:
            x, y, yaw = dynamics.step_pose(table, *pose, previous, action, rng)
            if dynamics.swept_path_blocked(scene.blocked, scene.grid, pose[:2], (x, y)):
                previous = int(dynamics.Action.HOVER)
            else:
                pose, previous = (x, y, yaw), action
            yield pose


def _box_sum(cumulative: np.ndarray, row: int, col: int, radius: int) -> int:
    """Sum over the square of half-side ``radius`` around (row, col) from a 2-D cumulative sum (clipped)."""
    r0, c0 = max(row - radius, 0) - 1, max(col - radius, 0) - 1
    r1, c1 = min(row + radius, cumulative.shape[0] - 1), min(col + radius, cumulative.shape[1] - 1)
    total = cumulative[r1, c1]
    if r0 >= 0:
        total -= cumulative[r0, c1]
    if c0 >= 0:
        total -= cumulative[r1, c0]
    if r0 >= 0 and c0 >= 0:
        total += cumulative[r0, c0]
    return int(total)


DEFAULT_EXPLORERS: tuple[Explorer, ...] = (
    RandomGoalWalk(greedy_prob=0.8),
    RandomGoalWalk(greedy_prob=0.2),
    PlannerExplorer("frontier"),
    PlannerExplorer("fuel"),
)


# ---- flying ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlightStep:
    """The state after one scan. ``maps`` is the flight's live map: copy what you keep."""

    step: int  # 0 = the scan at the start pose
    pose: Pose
    maps: ObservedMaps
    coverage: float  # observed-only coverage of the interior (DESIGN.md §7)


@dataclass(frozen=True)
class FlightLimits:
    """When a flight stops: after ``max_steps`` scans, or when the coverage has not grown for ``stall_steps``."""

    max_steps: int = 2000
    stall_steps: int = 150


DEFAULT_LIMITS = FlightLimits()
DEFAULT_SENSOR = SensorConfig()  # the training simulator's: 87° field of view, 4.5 m range, occupied noise 0.1


def fly(
    scene: Scene,
    explorer: Explorer,
    rng: np.random.Generator,
    sensor: SensorConfig = DEFAULT_SENSOR,
    limits: FlightLimits = DEFAULT_LIMITS,
    start: Pose | None = None,
) -> Iterator[FlightStep]:
    """Explore ``scene``: scan at the start, then at each pose the explorer proposes, yielding after every scan.

    Ends when the explorer stops proposing poses or at ``limits``.
    """
    maps = ObservedMaps.empty(scene.grid, LOW_RES_M)
    pose = scene.random_start(rng) if start is None else start
    poses = explorer.poses(scene, maps, pose, rng)
    best, best_step = -1.0, 0
    for step in range(limits.max_steps):
        if step > 0:
            pose = next(poses, None)
            if pose is None:  # the explorer has nothing left to explore
                return
        patch = scan(scene.occupied, scene.grid, pose[0], pose[1], pose[2], sensor, rng)
        maps.apply_patch(patch.row0, patch.col0, patch.codes)
        coverage = map_metrics(maps.low, scene.truth_low, scene.interior_low).coverage
        yield FlightStep(step, pose, maps, coverage)
        if coverage > best:
            best, best_step = coverage, step
        elif step - best_step >= limits.stall_steps:
            return


# ---- samples -----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleConfig:
    """How samples are drawn from the flights."""

    samples_per_plan: int = 8
    min_coverage: float = 0.02
    seed: int = 0
    limits: FlightLimits = DEFAULT_LIMITS
    noise_free_fraction: float = 0.0  # share of flights scanned without occupied-cell noise (the rest: DEFAULT_SENSOR)

    def __post_init__(self) -> None:
        if not 0.0 <= self.noise_free_fraction <= 1.0:
            raise ValueError(f"noise_free_fraction must be in [0, 1], got {self.noise_free_fraction}")


@dataclass(frozen=True)
class Sample:
    observed_low: np.ndarray  # int8 codes on the plan's 0.20 m grid
    robot_cell: tuple[int, int]  # (row, col) on that grid
    observed_area_m2: float
    coverage: float
    explorer: int  # index into the explorers of the run


def collect_plan_samples(
    scene: Scene, explorers: Sequence[Explorer], rng: np.random.Generator, config: SampleConfig = SampleConfig()
) -> list[Sample]:
    """Fly one plan with a random explorer of ``explorers``; record the map when each drawn coverage level is reached.

    With ``noise_free_fraction`` > 0 that share of the flights (drawn per plan) scans with a noise-free sensor, so the
    predictor learns from both kinds of maps the daemon meets. Levels the flight never reaches are replaced by its
    final map (the most it could see), recorded once.
    """
    which = int(rng.integers(len(explorers)))
    sensor = DEFAULT_SENSOR
    if config.noise_free_fraction > 0 and rng.random() < config.noise_free_fraction:
        sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=0.0)
    levels = list(np.sort(rng.uniform(config.min_coverage, 1.0, config.samples_per_plan)))
    samples: list[Sample] = []
    last: FlightStep | None = None

    def record(s: FlightStep) -> None:
        cell = scene.low_cell(s.pose[0], s.pose[1])
        samples.append(Sample(s.maps.low.copy(), cell, s.maps.observed_area_m2(), s.coverage, which))

    for s in fly(scene, explorers[which], rng, sensor=sensor, limits=config.limits):
        last = s
        if levels and s.coverage >= levels[0]:
            record(s)
            while levels and s.coverage >= levels[0]:
                levels.pop(0)
        if not levels:
            break
    if levels and last is not None and (not samples or samples[-1].coverage < last.coverage):
        record(last)
    return samples


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


# ---- the torch dataset -------------------------------------------------------------------------------------------
def dihedral(codes: np.ndarray, cell: tuple[int, int], k: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Symmetry ``k`` ∈ 0..7 of the square's group applied to a map and a cell on it: transpose if k ≥ 4, then
    flip rows if k & 1, flip columns if k & 2. k = 0 is the identity."""
    row, col = cell
    if k & 4:
        codes, row, col = codes.T, col, row
    if k & 1:
        codes, row = codes[::-1], codes.shape[0] - 1 - row
    if k & 2:
        codes, col = codes[:, ::-1], codes.shape[1] - 1 - col
    return codes, (row, col)


@dataclass(frozen=True)
class LossWeighting:
    """Per-cell BCE weights (:func:`edge_explorer.predict.encoding.loss_weights`)."""

    exterior_weight: float = 0.1
    observed_weight: float = 0.0
    wall_weight: float = 1.0


class PredictorDataset(torch.utils.data.Dataset):
    """(input 2×256×256, target 1×256×256, weight 1×256×256) float32 tensors of a :class:`SampleStore`.

    With ``augment``, sample ``i`` in epoch ``e`` takes the symmetry drawn from ``(seed, e, i)``, so a run is
    reproducible and a resumed run sees the same data; without it every sample is used as recorded.
    """

    def __init__(
        self,
        store: SampleStore,
        weighting: LossWeighting = LossWeighting(),
        augment: bool = False,
        seed: int = 0,
        size_cells: int = PREDICTOR_WINDOW_CELLS,
    ) -> None:
        self.store = store
        self.weighting = weighting
        self.augment = augment
        self.seed = seed
        self.size_cells = size_cells
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.store)

    def windows(self, index: int, symmetry: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(observed, truth) int8 ego windows of a sample under a symmetry."""
        store = self.store
        cell = (int(store.robot_cells[index, 0]), int(store.robot_cells[index, 1]))
        observed, ego_cell = dihedral(store.observed[index], cell, symmetry)
        truth, _ = dihedral(store.truth[store.sample_plan[index]], cell, symmetry)
        return pad_shift(observed, ego_cell, self.size_cells), pad_shift(truth, ego_cell, self.size_cells)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        symmetry = int(np.random.default_rng([self.seed, self.epoch, index]).integers(8)) if self.augment else 0
        observed, truth = self.windows(index, symmetry)
        w = self.weighting
        return (
            torch.from_numpy(encode_windows(observed)),
            torch.from_numpy(occupancy_target(truth)[None]),
            torch.from_numpy(loss_weights(truth, observed, w.exterior_weight, w.observed_weight, w.wall_weight)[None]),
        )


# ---- generating shards -------------------------------------------------------------------------------------------
SPLIT_IDS = {"train": 0, "val": 1, "test": 2}


@dataclass(frozen=True)
class ShardJob:
    plan_shard: Path  # a plans/<split>/shard-*.jsonl.gz
    split: str
    first: int  # plans [first, stop) of that file's lines
    stop: int
    out: Path  # the .npz to write; its .json marker is written last
    config: SampleConfig

    @property
    def marker(self) -> Path:
        return self.out.with_suffix(".json")


def _run_job(job: ShardJob) -> dict:
    from itertools import islice

    from edge_explorer.errors import PlanError
    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import iter_shard_plans

    t0 = time.perf_counter()
    scenes, samples, skipped = [], [], []
    for plan in islice(iter_shard_plans([job.plan_shard]), job.first, job.stop):
        try:
            scene = Scene.from_raster(plan_to_raster(plan))
        except PlanError as exc:
            skipped.append({"plan": plan.name, "error": str(exc)})
            continue
        index = int(plan.name.rsplit("-", 1)[-1])
        rng = np.random.default_rng([job.config.seed, SPLIT_IDS[job.split], index])
        scenes.append(scene)
        samples.append(collect_plan_samples(scene, DEFAULT_EXPLORERS, rng, job.config))
    job.out.parent.mkdir(parents=True, exist_ok=True)
    write_shard(job.out, scenes, samples)
    marker = {
        "format": SHARD_FORMAT,
        "version": SHARD_VERSION,
        "plans": len(scenes),
        "samples": sum(len(s) for s in samples),
        "skipped": skipped,
        "seconds": time.perf_counter() - t0,
        "source": str(job.plan_shard),
        "first": job.first,
        "stop": job.stop,
    }
    job.marker.write_text(json.dumps(marker))
    return marker


def plan_jobs(
    plans_dir: Path, out_dir: Path, split: str, plan_count: int, plans_per_shard: int, config: SampleConfig
) -> list[ShardJob]:
    """Jobs covering the first ``plan_count`` plans of ``plans_dir/split``, ``plans_per_shard`` plans per output."""
    sources = []
    for path in sorted((plans_dir / split).glob("shard-*.jsonl.gz")):
        marker = path.with_name(path.name.replace(".jsonl.gz", ".json"))
        count = json.loads(marker.read_text())["plans"] if marker.exists() else None
        if count is not None:
            sources.append((path, count))
    if not sources:
        raise EdgeExplorerError(f"{plans_dir / split}: no finished plan shards; run `edge-explorer plans generate`")
    jobs: list[ShardJob] = []
    remaining = plan_count
    for path, count in sources:
        for first in range(0, count, plans_per_shard):
            if remaining <= 0:
                return jobs
            stop = min(first + plans_per_shard, count, first + remaining)
            out = out_dir / split / f"shard-{len(jobs):05d}.npz"
            jobs.append(ShardJob(path, split, first, stop, out, config))
            remaining -= stop - first
    return jobs


@dataclass(frozen=True)
class DataReport:
    samples: int
    plans: int
    shards_done_before: int
    seconds: float


def generate_predictor_data(
    plans_dir: Path,
    out_dir: Path,
    plan_counts: dict[str, int],
    config: SampleConfig = SampleConfig(),
    plans_per_shard: int = 50,
    workers: int = 1,
    ray: str | None = None,
) -> DataReport:
    """Write sample shards for each split in ``plan_counts`` (e.g. ``{"train": 6000, "val": 200}``), resumably.

    The shards go to ``workers`` processes, or with ``ray`` (``"auto"`` or an address) to Ray tasks, which read
    ``plans_dir`` and write ``out_dir`` themselves: on a cluster both must be mounted at the same path everywhere."""
    from tqdm import tqdm

    manifest = {
        "format": SHARD_FORMAT,
        "version": SHARD_VERSION,
        "plans_dir": str(plans_dir),
        "plans_per_shard": plans_per_shard,
        "config": asdict(config),
        "explorers": [e.name for e in DEFAULT_EXPLORERS],
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = out_dir / "manifest.json"
    if manifest_path.exists():
        old = json.loads(manifest_path.read_text())
        if {k: v for k, v in old.items() if k != "plan_counts"} != manifest:
            raise EdgeExplorerError(f"{out_dir} holds samples made with other settings; use a new --out")
    manifest["plan_counts"] = plan_counts
    manifest_path.write_text(json.dumps(manifest, indent=1))
    jobs = [
        j for split, n in plan_counts.items() for j in plan_jobs(plans_dir, out_dir, split, n, plans_per_shard, config)
    ]
    todo = [j for j in jobs if not j.marker.exists()]
    t0 = time.perf_counter()
    samples = plans = 0
    with tqdm(total=sum(j.stop - j.first for j in todo), unit="plan", desc="predictor samples") as bar:
        for k, result in map_units(_run_job, todo, workers=workers, ray=ray):
            samples += result["samples"]
            plans += result["plans"]
            bar.update(todo[k].stop - todo[k].first)
            bar.set_postfix(samples=samples)
    return DataReport(samples, plans, len(jobs) - len(todo), time.perf_counter() - t0)
