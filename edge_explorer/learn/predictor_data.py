"""Training data for the map predictor: partial maps recorded while exploring floor plans, with their ground truth.

The flights and explorers are in :mod:`edge_explorer.learn.predictor_flights`, the shard format in
:mod:`edge_explorer.learn.predictor_shards`, the torch dataset in :mod:`edge_explorer.learn.predictor_dataset`.

Per plan, :func:`collect_plan_samples` flies one explorer drawn from
:data:`~edge_explorer.learn.predictor_flights.DEFAULT_EXPLORERS`, draws coverage levels uniformly in
[``min_coverage``, 1] and records the observed low-res map (0.20 m, in the plan's map frame) the first time each level
is reached, with the robot's low-res cell and the observed area; the truth is stored once per plan.
``SampleConfig.noise_free_fraction`` of the flights scan with a noise-free sensor, the rest with the training
noise (docs/design.md §6), so the predictor sees both kinds of maps.

:func:`generate_predictor_data` writes the shards in parallel, resumably (a ``.json`` marker is written last), from
the plan shards of :mod:`edge_explorer.world.dataset`: ``train`` from the train split, ``val`` from val.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
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
