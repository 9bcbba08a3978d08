"""Training data for the map predictor: partial maps recorded while exploring floor plans, with their ground truth.

The flights and explorers are in :mod:`edge_explorer.learn.predictor_flights`, the shard format in
:mod:`edge_explorer.learn.predictor_shards`, the torch dataset in :mod:`edge_explorer.learn.predictor_dataset`.

Per plan, :func:`collect_plan_samples` flies one explorer drawn from
:data:`~edge_explorer.learn.predictor_flights.DEFAULT_EXPLORERS`, draws coverage levels uniformly in
[``min_coverage``, 1] and records the observed low-res map (0.20 m, in the plan's map frame) the first time each level
is reached, with the robot's low-res cell and the observed area; the truth is stored once per plan.

**Whole floors** (issue #55: the predictor learned on buildings of at most 21 × 11 m and paints the unseen rest of a
whole floor solid). With ``floors`` the flights are the generated whole floors of the split (``floor-<split>-<k>``,
40–200 m, :mod:`edge_explorer.world.floors`) under :data:`FLOOR_SAMPLES`: a flight covers only part of a large floor
within its step cap, so coverage levels up to 1 would mostly go unreached, and the moments are drawn uniformly over
the flight's steps instead (``SampleConfig.by_step``); the 256 × 256 ego window the model sees (51 m) then lies
inside the building, with its unseen rooms and corridors as truth.
``SampleConfig.noise_free_fraction`` of the flights scan with a noise-free sensor, the rest with the training
noise (docs/design.md §6), so the predictor sees both kinds of maps.

:func:`generate_predictor_data` writes the shards in parallel, resumably (a ``.json`` marker is written last), from
the plan shards of :mod:`edge_explorer.world.dataset`: ``train`` from the train split, ``val`` from val.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.predictor_flights import (
    DEFAULT_EXPLORERS,
    DEFAULT_LIMITS,
    DEFAULT_SENSOR,
    Explorer,
    FlightLimits,
    FlightStep,
    Scene,
    fly,
)
from edge_explorer.learn.predictor_shards import SHARD_FORMAT, SHARD_VERSION, Sample, write_shard
from edge_explorer.world.raster import PlanRaster


# ---- samples -----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleConfig:
    """How samples are drawn from the flights."""

    samples_per_plan: int = 8
    min_coverage: float = 0.02
    seed: int = 0
    limits: FlightLimits = DEFAULT_LIMITS
    noise_free_fraction: float = 0.0  # share of flights scanned without occupied-cell noise (the rest: DEFAULT_SENSOR)
    by_step: bool = False  # draw the recording moments uniformly over the flight's step cap, not over coverage

    def __post_init__(self) -> None:
        if not 0.0 <= self.noise_free_fraction <= 1.0:
            raise ValueError(f"noise_free_fraction must be in [0, 1], got {self.noise_free_fraction}")


# How whole floors are sampled: 40 moments of a flight of at most 6,000 steps (a 200 m floor is about half explored
# by then; the smaller ones are done before it, and their later moments are the final map), stalls after 300 steps.
FLOOR_SAMPLES = SampleConfig(samples_per_plan=40, limits=FlightLimits(max_steps=6000, stall_steps=300), by_step=True)


def collect_plan_samples(
    scene: Scene, explorers: Sequence[Explorer], rng: np.random.Generator, config: SampleConfig = SampleConfig()
) -> list[Sample]:
    """Fly one plan with a random explorer of ``explorers``; record the map when each drawn coverage level (with
    ``by_step``: step) is reached.

    With ``noise_free_fraction`` > 0 that share of the flights (drawn per plan) scans with a noise-free sensor, so the
    predictor learns from both kinds of maps the daemon meets. Levels the flight never reaches are replaced by its
    final map (the most it could see), recorded once.
    """
    which = int(rng.integers(len(explorers)))
    sensor = DEFAULT_SENSOR
    if config.noise_free_fraction > 0 and rng.random() < config.noise_free_fraction:
        sensor = dataclasses.replace(DEFAULT_SENSOR, occupied_noise_prob=0.0)
    if config.by_step:
        levels = list(np.sort(rng.integers(0, config.limits.max_steps, config.samples_per_plan)).astype(float))
    else:
        levels = list(np.sort(rng.uniform(config.min_coverage, 1.0, config.samples_per_plan)))
    samples: list[Sample] = []
    last: FlightStep | None = None

    def record(s: FlightStep) -> None:
        cell = scene.low_cell(s.pose[0], s.pose[1])
        samples.append(Sample(s.maps.low.copy(), cell, s.maps.observed_area_m2(), s.coverage, which))

    for s in fly(scene, explorers[which], rng, sensor=sensor, limits=config.limits):
        last = s
        progress = float(s.step) if config.by_step else s.coverage
        if levels and progress >= levels[0]:
            record(s)
            while levels and progress >= levels[0]:
                levels.pop(0)
        if not levels:
            break
    if levels and last is not None and (not samples or samples[-1].coverage < last.coverage):
        record(last)
    return samples


# ---- generating shards -------------------------------------------------------------------------------------------
SPLIT_IDS = {"train": 0, "val": 1, "test": 2}


@dataclass(frozen=True)
class ShardJob:
    plan_shard: Path | None  # a plans/<split>/shard-*.jsonl.gz; None: the whole floors of ``split``
    split: str
    first: int  # plans [first, stop) of that file's lines, or floors [first, stop) of the split
    stop: int
    out: Path  # the .npz to write; its .json marker is written last
    config: SampleConfig

    @property
    def marker(self) -> Path:
        return self.out.with_suffix(".json")


_FLOOR_SALT = 0xF1002  # in a whole floor's flight seed: floor k and plan k of a split fly differently


def _plan_rasters(plan_shard: Path, first: int, stop: int, skipped: list[dict]) -> Iterator[PlanRaster]:
    """The rasters of plans [first, stop) of a plan shard; a plan that cannot be rasterized is noted in ``skipped``."""
    from itertools import islice

    from edge_explorer.errors import PlanError
    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import iter_shard_plans

    for plan in islice(iter_shard_plans([plan_shard]), first, stop):
        try:
            yield plan_to_raster(plan)
        except PlanError as exc:
            skipped.append({"plan": plan.name, "error": str(exc)})


def _run_job(job: ShardJob) -> dict:
    from edge_explorer.world.catalog import floor_rasters

    t0 = time.perf_counter()
    scenes, samples, skipped = [], [], []
    if job.plan_shard is None:  # whole floors: a seed the generator gives up on is skipped by floor_rasters
        rasters = iter(floor_rasters(job.split, job.first, job.stop))
        salt = [_FLOOR_SALT]
    else:
        rasters = _plan_rasters(job.plan_shard, job.first, job.stop, skipped)
        salt = []
    for raster in rasters:
        scene = Scene.from_raster(raster)
        index = int(raster.name.rsplit("-", 1)[-1])
        rng = np.random.default_rng([job.config.seed, SPLIT_IDS[job.split], index, *salt])
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
        "source": str(job.plan_shard) if job.plan_shard is not None else f"floors-{job.split}",
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


def floor_jobs(
    out_dir: Path, split: str, floor_count: int, floors_per_shard: int, config: SampleConfig
) -> list[ShardJob]:
    """Jobs covering whole floors [0, ``floor_count``) of ``split``, ``floors_per_shard`` floors per output."""
    return [
        ShardJob(
            None,
            split,
            first,
            min(first + floors_per_shard, floor_count),
            out_dir / split / f"shard-{k:05d}.npz",
            config,
        )
        for k, first in enumerate(range(0, floor_count, floors_per_shard))
    ]


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
    floors: bool = False,
) -> DataReport:
    """Write sample shards for each split in ``plan_counts`` (e.g. ``{"train": 6000, "val": 200}``), resumably;
    with ``floors`` the counts are whole floors of the split (module docstring) and ``plans_dir`` is not read.

    The shards go to ``workers`` processes, or with ``ray`` (``"auto"`` or an address) to Ray tasks, which read
    ``plans_dir`` and write ``out_dir`` themselves: on a cluster both must be mounted at the same path everywhere."""
    from tqdm import tqdm

    manifest = {
        "format": SHARD_FORMAT,
        "version": SHARD_VERSION,
        "plans_dir": "floors" if floors else str(plans_dir),
        "plans_per_shard": plans_per_shard,
        "config": asdict(config),
        "explorers": [e.name for e in DEFAULT_EXPLORERS],
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = out_dir / "manifest.json"
    if manifest_path.exists():
        old = json.loads(manifest_path.read_text())
        old.get("config", {}).setdefault("by_step", False)  # folders recorded before the setting existed
        if {k: v for k, v in old.items() if k != "plan_counts"} != manifest:
            raise EdgeExplorerError(f"{out_dir} holds samples made with other settings; use a new --out")
    manifest["plan_counts"] = plan_counts
    manifest_path.write_text(json.dumps(manifest, indent=1))
    jobs = [
        j
        for split, n in plan_counts.items()
        for j in (
            floor_jobs(out_dir, split, n, plans_per_shard, config)
            if floors
            else plan_jobs(plans_dir, out_dir, split, n, plans_per_shard, config)
        )
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
