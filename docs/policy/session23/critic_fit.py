"""Can the goal network's value head explain PPO's returns? (issue #21, session 23)

PPO's critic is one linear layer on the spatial mean of the GoalNet's deepest features, and behaviour cloning never
trains it. In both PPO runs of session 23 its explained variance stayed near 0, also through 4,096 decisions in which
it trained alone. This script flies the goal environment with a policy sampled from the network (as PPO's rollouts
do), records the features the value head sees and the discounted returns (γ = 0.99, PPO's reward scale 0.05), and fits
ridge regressions on half of the episodes, scored on the other half:

* the 64 pooled features (the best any linear value head on them could do);
* the episode's progress (F1 of M_thres, coverage, path so far, decision index), which the observation does not carry;
* both.

    python docs/policy/session23/critic_fit.py --weights models/policy/policy.safetensors --plans 30 --out fit.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from edge_explorer.bench.explore import load_predictor
from edge_explorer.learn.goal_demos import split_rasters
from edge_explorer.learn.goal_net import load_goal_net
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig
from edge_explorer.learn.goal_env import GoalEnv

GAMMA, SCALE = 0.99, 0.05  # PPOConfig's gamma and reward_scale


def discounted(rewards: list[float]) -> list[float]:
    """Discounted return from each decision of one finished episode."""
    out, total = [], 0.0
    for reward in reversed(rewards):
        total = reward + GAMMA * total
        out.append(total)
    return out[::-1]


def ridge_explained_variance(x: np.ndarray, y: np.ndarray, train: np.ndarray, lam: float = 1e-2) -> float:
    """Explained variance on the held-out rows (~train) of a ridge fit on standardised features of the train rows."""
    mean, std = x[train].mean(0), x[train].std(0) + 1e-8
    z = np.hstack([(x - mean) / std, np.ones((len(x), 1))])
    a = z[train]
    w = np.linalg.solve(a.T @ a + lam * len(a) * np.eye(a.shape[1]), a.T @ y[train])
    residual = y[~train] - z[~train] @ w
    return float(1.0 - residual.var() / y[~train].var())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default="models/policy/policy.safetensors")
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--first", type=int, default=3000, help="first train plan (PPO's envs use 0-1999)")
    parser.add_argument("--plans", type=int, default=30)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    net = load_goal_net(args.weights).eval()
    pooled: list[np.ndarray] = []
    net.value.register_forward_hook(lambda _m, inputs, _o: pooled.append(inputs[0][0].detach().numpy().copy()))
    predictor = load_predictor(args.predictor)
    rasters = split_rasters("data/plans", "train", args.first, args.first + args.plans)
    env = GoalEnv(rasters, EnvConfig(max_steps=1500, thresholds=thresholds_of(predictor)), predictor=predictor)
    rng = np.random.default_rng(0)
    features, progress, returns, episode_ids, values = [], [], [], [], []
    for episode in tqdm(range(args.plans), desc="critic fit"):
        observation, info = env.reset(seed=episode, options={"plan_index": episode})
        rewards, done, k = [], False, 0
        while not done:
            inputs = (torch.as_tensor(observation[key])[None] for key in ("high", "thres", "last_action"))
            with torch.no_grad():
                logits, value = net(*inputs)
            mask = env.action_masks()
            scores = np.where(mask, logits.flatten().numpy(), -np.inf)
            probs = np.exp(scores - scores.max())
            action = int(rng.choice(len(probs), p=probs / probs.sum()))
            features.append(pooled[-1])
            values.append(float(value[0]))
            progress.append([info.get("f1", 0.0), info.get("coverage", 0.0), info.get("path_length_m", 0.0), k])
            observation, reward, terminated, truncated, info = env.step(action)
            rewards.append(reward * SCALE)
            done, k = terminated or truncated, k + 1
        returns += discounted(rewards)
        episode_ids += [episode] * len(rewards)
    x_net, x_prog, y = np.array(features), np.array(progress), np.array(returns)
    train = np.array(episode_ids) % 2 == 0
    result = {
        "decisions": len(y),
        "episodes": args.plans,
        "return_mean": float(y.mean()),
        "return_std": float(y.std()),
        "ev_untrained_head": float(1.0 - (y - np.array(values)).var() / y.var()),
        "ev_linear_on_pooled_features": ridge_explained_variance(x_net, y, train),
        "ev_progress_only": ridge_explained_variance(x_prog, y, train),
        "ev_pooled_plus_progress": ridge_explained_variance(np.hstack([x_net, x_prog]), y, train),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
