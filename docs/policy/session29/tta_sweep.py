"""The goal policy with a left-right mirror at decision time (issue #21, session 29): a val sweep.

BC trains the policy on mirrored decisions too (``train_goal_bc``: a left-right mirror of the heading-up frame is
another valid decision), so the policy should score a mirrored observation as the mirror of its scores. It does so
only approximately; averaging the two score maps (test-time augmentation) removes the part of each decision that is
not mirror-symmetric, which is noise with respect to the expert it imitates. The wrapped policy flies through the
unchanged :class:`GoalPolicyPlanner`. Each run is ``expert_sweep.py``'s (the benchmark's run 0 on a val plan), so
the sweep pairs with the stored sweeps::

    PYTHONPATH=docs/policy python docs/policy/session29/tta_sweep.py --name s29_tta_40 --first 40 --count 96
    python docs/policy/expert_sweep.py --compare s29_tta_40 s24_si_last
"""

from __future__ import annotations

import argparse

import numpy as np
from expert_sweep import add_sweep_args, fly_run, fly_sweep

from edge_explorer.bench import explore as bench
from edge_explorer.plan.goal_policy import GoalPolicyPlanner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.raster import PlanRaster

MIRRORED_ACTION = np.array([0, 2, 1, 3, 5, 4])  # hover, right<->left, forward, right+fwd<->left+fwd
_WORKER: dict = {}


def mirrored(observation: dict) -> dict:
    """The observation of the left-right mirrored world: window columns flipped, turning motions swapped."""
    last = np.asarray(observation["last_action"]).reshape(-1)
    return {
        "high": np.ascontiguousarray(np.asarray(observation["high"])[..., ::-1]),
        "thres": np.ascontiguousarray(np.asarray(observation["thres"])[..., ::-1]),
        "last_action": last[MIRRORED_ACTION].reshape(np.shape(observation["last_action"])),
    }


class MirrorAveraged:
    """A goal policy whose scores are the mean of the policy's and the mirror of its scores on the mirror."""

    def __init__(self, policy, weight: float) -> None:
        self.policy, self.weight = policy, weight

    def __call__(self, observation: dict) -> np.ndarray:
        direct = np.asarray(self.policy(observation), dtype=np.float64)
        mirror = np.asarray(self.policy(mirrored(observation)), dtype=np.float64)[..., ::-1]
        return (1.0 - self.weight) * direct + self.weight * mirror


def _init(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    policy = bench.load_policy(args.policy)
    _WORKER.update(
        args=args, predictor=bench.load_predictor(args.predictor), policy=MirrorAveraged(policy, args.weight)
    )


def fly(raster: PlanRaster) -> tuple[str, float | None, int, int | None]:
    """``expert_sweep.fly``'s row: plan, path at 95 %, collisions, steps."""
    predictor = _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    env = ExplorationEnv(
        [raster], EnvConfig(coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor)), predictor
    )
    planner = GoalPolicyPlanner(_WORKER["policy"], table=env.table)
    at_goal, collisions, steps_at_goal, _ = fly_run(env, planner, raster, max_steps)
    return raster.name, at_goal, collisions, steps_at_goal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sweep_args(parser)
    parser.add_argument("--weight", type=float, default=0.5, help="share of the mirrored scores (0 = the policy)")
    args = parser.parse_args()
    runs = fly_sweep(args, fly, _init, (args,))
    paths = [r[1] for r in runs if r[1] is not None]
    print(
        f"{args.name}: mean path at 95 % {np.mean(paths):.2f} m, reached {len(paths)}/{len(runs)}, collisions "
        f"{sum(r[2] for r in runs)} -> runs/expert_sweep/{args.name}.json"
    )


if __name__ == "__main__":
    main()
