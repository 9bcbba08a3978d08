"""The generated floor-plan dataset: deterministic splits written as compressed shards (docs/design.md §4).

Plan ``k`` of split ``s`` is generated from a seed derived from (dataset seed, split, k) only, so any plan — and the
whole 100-plan test split — can be regenerated without the files, and a shard can be made on any core in any order.

Layout of ``OUT``::

    manifest.json                      seed, split sizes, shard size, generator version
    <split>/shard-00000.jsonl.gz       one plan JSON per line
    <split>/shard-00000.json           written last: plan count, skipped seeds, seconds  (marks the shard done)

A run that is interrupted resumes by skipping shards whose ``.json`` marker exists. A seed the generator cannot
turn into a valid plan is skipped, logged in the marker and reported; the run goes on.
"""

from __future__ import annotations

import gzip
import json
import os
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError, PlanError
from edge_explorer.world.plan import FloorPlan

SPLITS: tuple[str, ...] = ("train", "val", "test")
DEFAULT_SPLIT_SIZES: tuple[int, int, int] = (45_000, 4_900, 100)
DEFAULT_SEED = 0
SHARD_SIZE = 500


def plan_seed(dataset_seed: int, split: str, index: int) -> int:
    """The generator seed of plan ``index`` of ``split``: independent of shard size and core count."""
    state = np.random.SeedSequence([dataset_seed, SPLITS.index(split), index]).generate_state(2, dtype=np.uint32)
    return int(state[0]) << 32 | int(state[1])


def plan_name(split: str, index: int) -> str:
    return f"{split}-{index:05d}"


def generate_checked(dataset_seed: int, split: str, index: int) -> FloorPlan:
    """Generate one plan of a split; the generator only returns plans that pass every dataset rule
    (vector validation and connectivity at the robot radius on the 0.05 m raster) and raises PlanError otherwise."""
    from edge_explorer.world.generator import generate_plan

    return generate_plan(plan_seed(dataset_seed, split, index), plan_name(split, index))


def regenerate_split(split: str, count: int | None = None, dataset_seed: int = DEFAULT_SEED) -> list[FloorPlan]:
    """Regenerate a split in memory (the test split by default size), skipping seeds that fail."""
    if split not in SPLITS:
        raise EdgeExplorerError(f"unknown split {split!r}; choose one of {SPLITS}")
    n = DEFAULT_SPLIT_SIZES[SPLITS.index(split)] if count is None else count
    plans = []
    for k in range(n):
        try:
            plans.append(generate_checked(dataset_seed, split, k))
        except PlanError:
            continue
    return plans


@dataclass(frozen=True)
class ShardJob:
    out_dir: Path
    dataset_seed: int
    split: str
    shard: int
    start: int
    stop: int

    @property
    def data_path(self) -> Path:
        return self.out_dir / self.split / f"shard-{self.shard:05d}.jsonl.gz"

    @property
    def marker_path(self) -> Path:
        return self.data_path.with_name(f"shard-{self.shard:05d}.json")


def _run_shard(job: ShardJob) -> dict:
    t0 = time.perf_counter()
    lines, skipped = [], []
    for k in range(job.start, job.stop):
        try:
            plan = generate_checked(job.dataset_seed, job.split, k)
        except PlanError as exc:
            skipped.append({"index": k, "seed": plan_seed(job.dataset_seed, job.split, k), "error": str(exc)})
            continue
        lines.append(json.dumps(plan.to_dict(), separators=(",", ":")))
    job.data_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = job.data_path.with_suffix(".tmp")
    with gzip.open(tmp, "wt", compresslevel=6) as fh:
        fh.write("\n".join(lines) + ("\n" if lines else ""))
    os.replace(tmp, job.data_path)
    marker = {"plans": len(lines), "skipped": skipped, "seconds": time.perf_counter() - t0}
    job.marker_path.write_text(json.dumps(marker))
    return marker


def plan_jobs(out_dir: Path, dataset_seed: int, sizes: tuple[int, ...]) -> list[ShardJob]:
    jobs = []
    for split, size in zip(SPLITS, sizes, strict=True):
        for shard, start in enumerate(range(0, size, SHARD_SIZE)):
            jobs.append(ShardJob(out_dir, dataset_seed, split, shard, start, min(start + SHARD_SIZE, size)))
    return jobs


def _check_manifest(out_dir: Path, manifest: dict) -> None:
    path = out_dir / "manifest.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old != manifest:
            raise EdgeExplorerError(
                f"{out_dir} holds a dataset made with other settings ({old}); pass a new --out or the same settings"
            )
    else:
        out_dir.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(manifest, indent=1))


@dataclass(frozen=True)
class GenerationReport:
    plans: int
    skipped: list[dict]
    shards_done_before: int
    seconds: float

    @property
    def plans_per_s(self) -> float:
        return self.plans / self.seconds if self.seconds > 0 else float("nan")


def generate_dataset(
    out_dir: Path,
    count: int,
    dataset_seed: int,
    split_fractions: tuple[int, ...],
    workers: int,
    ray: str | None = None,
) -> GenerationReport:
    """Generate ``count`` plans split in the ratio ``split_fractions`` into shards, in parallel, resumably.

    The shards go to ``workers`` processes, or with ``ray`` (``"auto"`` or an address) to Ray tasks, which write
    into ``out_dir`` themselves: on a cluster it must be a folder every node mounts at the same path."""
    from tqdm import tqdm

    from edge_explorer.world.generator import GENERATOR_VERSION

    total = sum(split_fractions)
    sizes = [count * f // total for f in split_fractions]
    sizes[0] += count - sum(sizes)
    manifest = {
        "seed": dataset_seed,
        "splits": dict(zip(SPLITS, sizes, strict=True)),
        "shard_size": SHARD_SIZE,
        "generator_version": GENERATOR_VERSION,
    }
    _check_manifest(out_dir, manifest)
    jobs = plan_jobs(out_dir, dataset_seed, tuple(sizes))
    todo = [j for j in jobs if not j.marker_path.exists()]
    t0 = time.perf_counter()
    plans, skipped = 0, []
    with tqdm(total=sum(j.stop - j.start for j in todo), unit="plan", desc="plans") as bar:
        for k, result in map_units(_run_shard, todo, workers=workers, ray=ray):
            plans += result["plans"]
            skipped += result["skipped"]
            bar.update(todo[k].stop - todo[k].start)
            bar.set_postfix(plans_per_s=f"{plans / max(time.perf_counter() - t0, 1e-9):.0f}")
    return GenerationReport(plans, skipped, len(jobs) - len(todo), time.perf_counter() - t0)


def iter_shard_plans(shards: Iterable[Path]) -> Iterator[FloorPlan]:
    """Read plans back from ``*.jsonl.gz`` shards (validated on load)."""
    for shard in shards:
        with gzip.open(shard, "rt") as fh:
            for lineno, line in enumerate(fh, 1):
                if line.strip():
                    yield FloorPlan.from_dict(json.loads(line), f"{shard}:{lineno}")
