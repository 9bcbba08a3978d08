"""Fly the predictive expert (or the goal policy) with planner-setting overrides on val plans: the sweep that chose
the expert's settings (docs/policy/goal_policy.md; the session notes are in git history).

Each run is the benchmark's run (``bench explore``'s start pose, noise seed and end rule: 95 % coverage and 95 %
correct coverage, 1500 steps) on one val plan, so the figures pair with ``bench explore --plans`` on the same
plans. Overrides are fields of :class:`~edge_explorer.plan.predictive.PredictiveConfig`, or with a ``follow.`` prefix
fields of the path follower's :class:`~edge_explorer.plan.follow.FollowConfig` (every planner flies it), with a
``planner.`` prefix of the goal loop's :class:`~edge_explorer.plan.frontier.PlannerConfig`::

    python scripts/expert_sweep.py --name open --first 40 --count 96 open_prediction=True
    python scripts/expert_sweep.py --name nf03 --first 136 --count 96 near_fallback_ratio=0.3
    python scripts/expert_sweep.py --name nf --first 40 --count 96 --planner frontier
    python scripts/expert_sweep.py --name ns4 --first 40 --count 96 follow.noise_sigmas=4
    python scripts/expert_sweep.py --name gr1 --first 40 --count 96 planner.goal_radius_m=1.0
    python scripts/expert_sweep.py --name x2 --first 40 --count 96 --noise-scale 2  # a vehicle twice as noisy
    python scripts/expert_sweep.py --name drl --first 40 --count 32 --planner drl --policy models/policy

It prints the mean path at 95 % coverage, runs that reached it and collisions, and writes every run to
``runs/expert_sweep/NAME.json``. Two sweeps of the same plans pair run by run (mean ± s.e. of A − B)::

    python scripts/expert_sweep.py --compare s15_lam0.15 s14_drl

Tune on val plans only: the test split and A-D are the acceptance.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.plan.follow import FollowConfig
from edge_explorer.plan.frontier import NearestFrontier, PlannerConfig
from edge_explorer.plan.goal_policy import GoalPolicyPlanner
from edge_explorer.plan.predictive import PredictiveConfig, PredictiveFrontier
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.vehicle.dynamics import VehicleModel, write_action_table
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans
from edge_explorer.world.raster import PlanRaster

_WORKER: dict = {}


def _typed(pair: str, fields: dict) -> tuple[str, object]:
    key, _, value = pair.partition("=")
    if key not in fields or not isinstance(fields[key], (bool, int, float)) or not value:
        raise SystemExit(f"{pair!r}: expected key=value with key one of {sorted(fields)}")
    default = fields[key]
    return key, value == "True" if isinstance(default, bool) else type(default)(float(value))


_NESTED = {"follow": FollowConfig, "planner": PlannerConfig}  # prefixed overrides: the config class they go to


def parse_overrides(pairs: list[str]) -> dict:
    """``key=value`` pairs → PredictiveConfig keyword arguments, typed like the fields' defaults; ``follow.key=value``
    and ``planner.key=value`` pairs go under the ``follow`` and ``planner`` keys of the result."""
    out: dict = {}
    for pair in pairs:
        prefix, dot, rest = pair.partition(".")
        if dot and prefix in _NESTED:
            key, value = _typed(rest, {f.name: f.default for f in dataclasses.fields(_NESTED[prefix])})
            out.setdefault(prefix, {})[key] = value
        else:
            key, value = _typed(pair, {f.name: f.default for f in dataclasses.fields(PredictiveConfig)})
            out[key] = value
    return out


def predictive_config(overrides: dict) -> PredictiveConfig:
    """The planner settings of a sweep: the defaults with ``overrides`` (as :func:`parse_overrides` returns them)."""
    base = PredictiveConfig()
    rest = {k: v for k, v in overrides.items() if k not in _NESTED}
    follow = dataclasses.replace(base.planner.follow, **overrides.get("follow", {}))
    planner = dataclasses.replace(base.planner, follow=follow, **overrides.get("planner", {}))
    return dataclasses.replace(base, planner=planner, **rest)


def scaled_noise_table(scale: float) -> str | None:
    """Path of an action table whose motion noise is ``scale`` times the shipped vehicle's (written under
    runs/expert_sweep/), or ``None`` for the shipped table. The planners read it from the env, so they know it."""
    if scale == 1.0:
        return None
    model = VehicleModel()
    noisy = dataclasses.replace(
        model,
        pos_noise_floor_m=scale * model.pos_noise_floor_m,
        pos_noise_frac=scale * model.pos_noise_frac,
        yaw_noise_floor_rad=scale * model.yaw_noise_floor_rad,
        yaw_noise_frac=scale * model.yaw_noise_frac,
    )
    path = _sweep_path(f"action_table_noise_x{scale:g}").with_suffix(".table.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    return str(write_action_table(path, noisy))


def _init(args: argparse.Namespace, overrides: dict) -> None:
    _WORKER.update(args=args, config=predictive_config(overrides), predictor=bench.load_predictor(args.predictor))
    if args.planner == "drl":
        _WORKER["policy"] = bench.load_policy(args.policy)


def fly(raster: PlanRaster) -> tuple[str, float | None, int, int | None]:
    """(plan, path at 95 % coverage or None, collisions, steps to 95 % coverage or None) of one benchmark run on
    ``raster``: the steps are the flight time in control steps (turns in place add steps, not path)."""
    args, predictor = _WORKER["args"], _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    config = EnvConfig(
        coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor), action_table_path=args.table
    )
    env = ExplorationEnv([raster], config, predictor=predictor)
    if args.planner == "drl":
        planner = GoalPolicyPlanner(_WORKER["policy"], _WORKER["config"], env.table)
    elif args.planner == "frontier":
        planner = NearestFrontier(_WORKER["config"].planner, env.table)
    else:
        planner = PredictiveFrontier(_WORKER["config"], env.table)
    at_goal, collisions, steps_at_goal, _ = fly_run(env, planner, raster, max_steps)
    return raster.name, at_goal, collisions, steps_at_goal


def fly_run(
    env: ExplorationEnv, planner, raster: PlanRaster, max_steps: int
) -> tuple[float | None, int, int | None, bool]:
    """(path at 95 % coverage or None, collisions, steps to it or None, whether 95 % correct coverage was reached
    too) of ``planner`` flying the benchmark's run 0 on ``raster`` in ``env``."""
    planner.reset()
    _, info = env.reset(seed=bench.run_seed(0, raster.name, 0), options={"start_pose": bench.start_pose(raster, 0)})
    previous, collisions, at_goal, steps_at_goal = 0, 0, None, None
    for step in range(max_steps):
        if info["coverage"] >= 0.95 and at_goal is None:
            at_goal, steps_at_goal = float(info["path_length_m"]), step
        if info["coverage"] >= 0.95 and info["correct_coverage"] >= 0.95:
            return at_goal, collisions, steps_at_goal, True
        action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
        if action is None:
            break
        _, _, _, _, info = env.step(action)
        collisions += int(info["collided"])
        previous = 0 if info["collided"] else action
    return at_goal, collisions, steps_at_goal, False


def add_sweep_args(parser: argparse.ArgumentParser) -> None:
    """The options every policy sweep script shares (``--name`` and the plans, models and workers of
    :func:`fly_sweep`)."""
    parser.add_argument("--name", required=True, help="the sweep's name (runs/expert_sweep/NAME.json)")
    parser.add_argument("--first", type=int, default=40, help="first val plan")
    parser.add_argument("--count", type=int, default=96)
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy/policy.safetensors")
    parser.add_argument("--plans", type=Path, default=Path("data/plans/val"), help="the val split's shards")
    parser.add_argument("--workers", type=int, default=1)


def fly_sweep(args: argparse.Namespace, fly, initializer, initargs: tuple = ()) -> list:
    """Fly ``fly`` (a raster → row function) over val plans ``args.first`` … ``args.first + args.count − 1`` of
    ``args.plans`` in ``args.workers`` processes set up by ``initializer(*initargs)``; writes the rows with ``args``
    to ``runs/expert_sweep/{args.name}.json`` (the files :func:`compare` pairs) and returns them."""
    shards = sorted(Path(args.plans).glob("*.jsonl.gz"))
    if not shards:
        raise SystemExit(f"{args.plans}: no plan shards; generate them with `edge-explorer plans generate`")
    plans = [plan_to_raster(p) for p in itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)]
    with Pool(args.workers, initializer=initializer, initargs=initargs) as pool:
        runs = list(tqdm(pool.imap(fly, plans), total=len(plans), desc=args.name))
    out = _sweep_path(args.name)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "runs": runs}))
    return runs


def compare(name_a: str, name_b: str) -> str:
    """Paired path at 95 % of two sweeps ``runs/expert_sweep/{A,B}.json`` over the plans both reached it on."""
    for name in (name_a, name_b):
        if not _sweep_path(name).is_file():
            raise SystemExit(f"{_sweep_path(name)}: no such sweep; fly it first with --name {name}")
    a, b = ({r[0]: r for r in json.loads(_sweep_path(n).read_text())["runs"]} for n in (name_a, name_b))
    plans = [p for p in a if p in b and a[p][1] is not None and b[p][1] is not None]
    d = np.array([a[p][1] - b[p][1] for p in plans])
    mean_a, mean_b = np.mean([a[p][1] for p in plans]), np.mean([b[p][1] for p in plans])
    steps = [np.mean([s[p][3] for p in plans]) if all(len(s[p]) > 3 for p in plans) else None for s in (a, b)]
    step_text = f", steps to 95 % {steps[0]:.0f} vs {steps[1]:.0f}" if None not in steps else ""
    return (
        f"{name_a} - {name_b}: {d.mean():+.2f} ± {d.std(ddof=1) / np.sqrt(len(d)):.2f} m over {len(d)} plans "
        f"({mean_a:.2f} vs {mean_b:.2f} m), shorter on {(d < 0).sum()}, collisions {sum(r[2] for r in a.values())} "
        f"vs {sum(r[2] for r in b.values())}{step_text}"
    )


def _sweep_path(name: str) -> Path:
    return Path("runs/expert_sweep") / f"{name}.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", help="PredictiveConfig fields, key=value")
    parser.add_argument("--name", help="the sweep's name (its runs go to runs/expert_sweep/NAME.json)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"), help="print A − B of two finished sweeps and exit")
    parser.add_argument("--first", type=int, default=40, help="first val plan")
    parser.add_argument("--count", type=int, default=96)
    parser.add_argument("--planner", choices=("predfrontier", "frontier", "drl"), default="predfrontier")
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy")
    parser.add_argument("--plans", type=Path, default=Path("data/plans/val"), help="the val split's shards")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--noise-scale", type=float, default=1.0, help="motion noise × this (a stress test)")
    args = parser.parse_args()
    if args.compare:
        print(compare(*args.compare))
        return
    if not args.name:
        raise SystemExit("--name is required to fly a sweep")
    overrides = parse_overrides(args.overrides)
    args.table = scaled_noise_table(args.noise_scale)
    shards = sorted(args.plans.glob("*.jsonl.gz"))
    if not shards:
        raise SystemExit(f"{args.plans}: no plan shards; generate them with `edge-explorer plans generate`")
    plans = [plan_to_raster(p) for p in itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)]
    with Pool(args.workers, initializer=_init, initargs=(args, overrides)) as pool:
        runs = list(tqdm(pool.imap(fly, plans), total=len(plans), desc=args.name))
    paths = [r[1] if r[1] is not None else float("nan") for r in runs]
    out = _sweep_path(args.name)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args) | {"plans": str(args.plans)}, "overrides": overrides, "runs": runs}))
    reached = sum(r[1] is not None for r in runs)
    print(
        f"{args.name}: mean path at 95 % {np.nanmean(paths):.2f} m, reached {reached}/{len(runs)}, "
        f"collisions {sum(r[2] for r in runs)} ({overrides or 'defaults'}) -> {out}"
    )


if __name__ == "__main__":
    main()
