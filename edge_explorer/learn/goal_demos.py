"""Demonstrations for the goal policy: decisions labelled with the predictive expert's goal choice.

:class:`LabellingPlanner` flies one episode and, at every decision of the planner loop, records the observation,
the mask of valid goal cells and the cell of the goal the expert (:class:`~edge_explorer.plan.predictive.
PredictiveFrontier`) would choose on the same view. Without a policy it flies the expert's goals (behaviour-cloning
data); with one it flies the policy's goals while still recording the expert's labels — DAgger's aggregation step,
which shows the policy the states its own mistakes lead to.

Episodes run in the training simulator with the predictor on (phase 2 of the paper: the fused map is what the
policy sees), from the plans of the generated dataset (``data/plans``) or the generated whole floors
(:mod:`edge_explorer.world.floors`, ``floors=True``), until coverage and correct coverage reach 95 % or the step cap.
They fly inside the planning hierarchy (:class:`~edge_explorer.plan.window.WindowedPlanner`), as the bench and the
daemon do: on a plan that fits its window nothing changes, and on a whole floor the decisions are those of the
learned planner's window, with its whole-floor targets and settings (issue #55: the models had never seen a
corridor longer than 21 m). Shards are ``.npz`` files (plain arrays, no pickles), one per block of plans, written in
parallel and resumably (a ``.json`` marker is written last): ``high``/``thres`` int8 (N, 237, 237),
``last_action`` int8 (N,), ``mask`` packed bits (N, 436), ``label`` int32 (N,).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import OBSERVATION_WINDOW_CELLS
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.goal_policy import GoalPolicy, GoalPolicyPlanner, expert_label, goal_decision
from edge_explorer.plan.predictive import PredictiveFrontier
from edge_explorer.plan.window import WindowedPlanner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.sim.episode import Episode
from edge_explorer.vehicle.dynamics import ActionTable
from edge_explorer.world.raster import PlanRaster

DEMO_FORMAT = "edge-explorer/goal-demos"
_CELLS = GOAL_GRID_CELLS * GOAL_GRID_CELLS
Record = tuple[np.ndarray, np.ndarray, int, np.ndarray, int]  # high, thres, last motion, flat valid mask, label


class LabellingPlanner(GoalPolicyPlanner):
    """The expert's loop; the expert's or a policy's goals; every decision recorded with the expert's label.

    It is the learned planner (:class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`) that also asks the expert
    at every decision and flies the expert's goal when it has no ``policy``: so on a whole floor its targets, goal
    options and settings are the learned planner's there (:meth:`on_whole_floor`), and each label is the expert's
    choice among the options the policy is shown in flight."""

    def __init__(self, policy: GoalPolicy | None = None, table: ActionTable | None = None) -> None:
        super().__init__(policy, table=table)  # type: ignore[arg-type]  # without a policy the expert flies
        self.records: list[Record] = []

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        expert = PredictiveFrontier.select_goal(self, view, pose)
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        label = None if expert is None else expert_label(expert, pose, view, decision.options)
        if label is not None:
            o = decision.observation
            self.records.append((o["high"], o["thres"], self.last_action, decision.options.flat_mask(), label))
        if self.policy is None or not decision.options.mask.any():
            return expert
        return self.policy_goal(view, decision, self.policy(decision.observation), fused)


@dataclass(frozen=True)
class DemoConfig:
    """How demonstration episodes are flown."""

    max_steps: int = 1500
    coverage_goal: float = 0.95
    seed: int = 0


def fly_demo(
    raster: PlanRaster, predictor: Predictor | None, seed: int, config: DemoConfig, policy: GoalPolicy | None = None
) -> list[Record]:
    """One labelled episode on ``raster`` from a random start, inside the planning hierarchy (see the module
    docstring)."""
    env_config = EnvConfig(coverage_goal=1.0, max_steps=config.max_steps, thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], env_config, predictor=predictor)
    labelling = LabellingPlanner(policy, env.table)
    planner = WindowedPlanner(labelling)
    planner.reset()
    _, info = env.reset(seed=seed)
    Episode(env, planner, info, coverage_goal=config.coverage_goal, max_steps=config.max_steps).run()
    return labelling.records


def write_demos(path: Path, records: Sequence[Record]) -> None:
    """One shard of records (see the module docstring for the arrays), written atomically."""
    window = (OBSERVATION_WINDOW_CELLS, OBSERVATION_WINDOW_CELLS)
    arrays = {
        "high": np.array([r[0] for r in records], dtype=np.int8).reshape(-1, *window),
        "thres": np.array([r[1] for r in records], dtype=np.int8).reshape(-1, *window),
        "last_action": np.array([r[2] for r in records], dtype=np.int8),
        "mask": np.packbits(np.array([r[3] for r in records], dtype=bool).reshape(-1, _CELLS), axis=1),
        "label": np.array([r[4] for r in records], dtype=np.int32),
    }
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(path)


@dataclass(frozen=True)
class Demos:
    """Loaded shards: arrays as in the module docstring, the mask unpacked to bool (N, 3481)."""

    high: np.ndarray
    thres: np.ndarray
    last_action: np.ndarray
    mask: np.ndarray
    label: np.ndarray

    def __len__(self) -> int:
        return len(self.label)


def load_demos(folder: str | Path) -> Demos:
    """Every finished shard (with its marker) of ``folder`` — or of each of several folders, comma-separated (e.g.
    the expert's demonstrations and a DAgger round's)."""
    folders = [Path(f) for f in str(folder).split(",") if f]
    paths = [p for f in folders for p in sorted(f.glob("shard-*.npz")) if p.with_suffix(".json").exists()]
    if not paths:
        raise EdgeExplorerError(f"{folder}: no finished demonstration shards; run `edge-explorer train goal-demos`")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("high", "thres", "last_action", "mask", "label")}
    for path in paths:
        with np.load(path) as data:
            for key in parts:
                parts[key].append(data[key])
    mask = np.unpackbits(np.concatenate(parts["mask"]), axis=1, count=_CELLS).astype(bool)
    return Demos(
        np.concatenate(parts["high"]),
        np.concatenate(parts["thres"]),
        np.concatenate(parts["last_action"]),
        mask,
        np.concatenate(parts["label"]),
    )


@dataclass(frozen=True)
class DemoJob:
    plans: str  # plan dataset folder
    split: str
    first: int  # plan indices [first, stop) of the split
    stop: int
    out: Path
    predictor: str | None
    policy: str | None
    config: DemoConfig
    floors: bool = False  # the generated whole floors of ``split`` instead of the plans in ``plans``

    @property
    def marker(self) -> Path:
        return self.out.with_suffix(".json")


def split_rasters(
    plans_dir: str, split: str, first: int, stop: int, every: int = 1, offset: int = 0
) -> list[PlanRaster]:
    """Plans [first, stop) of a split of the generated dataset in ``plans_dir``, rasterized at 0.05 m; with
    ``every`` > 1 only each ``every``-th of them from ``offset`` (one worker's share, the others never rasterized)."""
    from itertools import islice

    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import iter_shard_plans

    shards = sorted((Path(plans_dir) / split).glob("shard-*.jsonl.gz"))
    return [plan_to_raster(p) for p in islice(iter_shard_plans(shards), first + offset, stop, every)]


def _run_job(job: DemoJob) -> dict:
    import cv2

    from edge_explorer.learn.loaders import load_policy, load_predictor

    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    predictor = load_predictor(job.predictor) if job.predictor else None
    policy = None
    if job.policy:
        if job.policy.endswith(".safetensors"):
            import torch

            torch.set_num_threads(1)  # one process per core: torch's own threads would oversubscribe them
        policy = load_policy(job.policy)  # torch weights, or an exported folder (int8 TFLite: faster rollouts)
    from edge_explorer.world.catalog import floor_rasters

    records = []
    rasters = (
        floor_rasters(job.split, job.first, job.stop)
        if job.floors
        else split_rasters(job.plans, job.split, job.first, job.stop)
    )
    for k, raster in enumerate(rasters):
        seed = int(np.random.SeedSequence([job.config.seed, job.first + k]).generate_state(1)[0])
        records += fly_demo(raster, predictor, seed, job.config, policy)
    job.out.parent.mkdir(parents=True, exist_ok=True)
    write_demos(job.out, records)
    job_fields = json.loads(json.dumps(asdict(job), default=str))  # paths as text
    marker = {"format": DEMO_FORMAT, "decisions": len(records), "seconds": time.perf_counter() - t0, **job_fields}
    job.marker.write_text(json.dumps(marker))
    return marker


def generate_demos(
    plans_dir: str,
    out_dir: Path,
    split: str,
    plan_range: tuple[int, int],
    predictor: str | None,
    policy: str | None = None,
    plans_per_shard: int = 10,
    workers: int = 1,
    config: DemoConfig = DemoConfig(),
    floors: bool = False,
) -> int:
    """Write demonstration shards for plans ``plan_range`` of ``split`` (of the whole floors with ``floors``),
    resumably; returns the decisions written this call (shards already finished are skipped)."""
    from tqdm import tqdm

    first, stop = plan_range
    jobs = [
        DemoJob(
            plans_dir,
            split,
            a,
            min(a + plans_per_shard, stop),
            out_dir / f"shard-{a:06d}.npz",
            predictor,
            policy,
            config,
            floors,
        )
        for a in range(first, stop, plans_per_shard)
    ]
    todo = [j for j in jobs if not j.marker.exists()]
    decisions = 0
    with tqdm(total=sum(j.stop - j.first for j in todo), unit="plan", desc="goal demos") as bar:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_run_job, j): j for j in todo}
            for future in as_completed(futures):
                decisions += future.result()["decisions"]
                job = futures[future]
                bar.update(job.stop - job.first)
                bar.set_postfix(decisions=decisions)
    return decisions
