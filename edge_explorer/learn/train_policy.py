"""Training the DRL exploration planner: behaviour-cloning warm start, then PPO in two phases (DESIGN.md §6).

``edge-explorer train policy --config CONFIG.toml --out DIR [--resume] [--device cpu|cuda] [--max-minutes N]``

Stages, each recorded in ``DIR/state.json`` so that ``--resume`` continues where a run stopped:

1. **expert** — an expert planner (``frontier`` or ``fuel``, :mod:`edge_explorer.plan.baselines`) flies the same
   six-action vehicle in the training simulator on train plans; every step's observation, the expert's action and
   the (scaled) reward are written per episode to ``DIR/expert/episode-NNNNN.npz`` (an episode already on disk is
   not flown again). Episodes run in ``n_envs`` worker processes (in-process for one).
2. **bc** — the actor is trained to imitate the expert (cross-entropy), and the value head to predict the expert's
   discounted return (MSE), on the shared features; ``bc.csv`` logs loss and held-out accuracy per epoch. The val
   evaluation before and after BC lands in ``eval.csv`` (stage ``init`` / ``bc``): how much BC contributed.
3. **phase1** — PPO (stable-baselines3) without the predictor: reward on the observed map's F1. With
   ``curriculum_steps`` > 0 episodes start on the ``curriculum_start_fraction`` of the train plans with the smallest
   interior area, the fraction growing linearly to all plans over that many PPO steps: small buildings can be
   finished within ``max_steps``, so early PPO sees the goal reward instead of only truncated episodes.
4. **phase2** — PPO with the predictor in every environment, thresholds annealed linearly from
   (``anneal_start_t_f_max``, ``anneal_start_t_o``) to the defaults (t_f_max 0.04, t_o 0.94) over the phase.

PPO runs on ``n_envs`` ``SubprocVecEnv`` workers (in-process ``DummyVecEnv`` for one); every
``checkpoint_every_steps`` the SB3 model is saved to ``DIR/checkpoint.zip`` (SB3's zip, only for ``--resume`` inside
runs/); every ``eval_every_steps`` the deterministic policy flies ``eval_episodes`` val plans (fixed seeds) and the
best actor so far — most successes, then highest coverage less 0.01 per collision per episode, then shortest mean
path — is written to ``DIR/best.safetensors`` (every evaluated actor to ``DIR/evaluated/``;
:func:`~edge_explorer.learn.policy_net.save_policy`, the shippable format). SB3's own logs go to
``DIR/progress.csv`` (kept as ``progress-until-STEPS.csv`` when a run resumes) and TensorBoard event files in ``DIR``.
Rewards are multiplied by ``reward_scale`` for learning only (the environment's l and ω are unchanged), so
returns stay of order one for the value head that shares the convolutional features.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn import toml_config
from edge_explorer.learn.csv_log import append_csv_row
from edge_explorer.learn.policy_net import PolicyNetConfig, save_policy, sb3_policy_kwargs
from edge_explorer.mapping.ego import NUM_ACTIONS
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.plan import FloorPlan

STAGES = ("expert", "bc", "phase1", "phase2", "done")
EXPERTS = ("frontier", "fuel", "none")


@dataclass(frozen=True)
class PolicyTrainConfig:
    """Everything a training run depends on (TOML keys of the same names; see configs/policy.toml)."""

    # plans: the first N plans of the generated train / val splits (regenerated deterministically)
    train_plans: int = 200
    val_plans: int = 8
    seed: int = 0
    threads: int = 1  # torch intra-op threads per process
    n_envs: int = 2
    # the task (EnvConfig)
    coverage_goal: float = 0.95
    max_steps: int = 500
    collision_penalty: float = 10.0
    f1_weight: float = 100.0
    reward_scale: float = 0.05
    # network
    conv_channels: tuple[int, ...] = (16, 32, 32)
    conv_kernels: tuple[int, ...] = (8, 4, 3)
    conv_strides: tuple[int, ...] = (4, 2, 2)
    pi_layers: tuple[int, ...] = (256,)
    vf_layers: tuple[int, ...] = (256,)
    input_pool: int = 1
    # curriculum: PPO episodes start on the smallest-interior fraction of the train plans, growing linearly to all
    curriculum_steps: int = 0  # PPO steps until every plan is in play (0: no curriculum)
    curriculum_start_fraction: float = 0.25
    # behaviour cloning
    expert: str = "frontier"
    expert_episodes: int = 40
    bc_epochs: int = 3
    bc_batch_size: int = 64
    bc_learning_rate: float = 3e-4
    bc_value_weight: float = 0.5
    bc_holdout: float = 0.1  # fraction of expert episodes held out for accuracy
    # PPO
    phase1_steps: int = 20_000
    phase2_steps: int = 0
    predictor: str = "models/predictor/predictor.safetensors"  # .safetensors (torch) or an export's card.json
    anneal_start_t_f_max: float = 0.001
    anneal_start_t_o: float = 0.999
    learning_rate: float = 1e-4
    n_steps: int = 256
    batch_size: int = 128
    n_epochs: int = 4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.1
    ent_coef: float = 0.001
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.03
    # bookkeeping
    eval_every_steps: int = 4096
    eval_episodes: int = 8
    checkpoint_every_steps: int = 2048

    def __post_init__(self) -> None:
        positive = (
            "train_plans", "val_plans", "threads", "n_envs", "max_steps", "bc_batch_size", "n_steps", "batch_size",
            "n_epochs", "eval_every_steps", "eval_episodes", "checkpoint_every_steps",
        )  # fmt: skip
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        for name in ("expert_episodes", "bc_epochs", "phase1_steps", "phase2_steps", "curriculum_steps"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be ≥ 0, got {getattr(self, name)}")
        if self.expert not in EXPERTS:
            raise ValueError(f"expert must be one of {EXPERTS}, got {self.expert!r}")
        if not 0 < self.curriculum_start_fraction <= 1:
            raise ValueError(f"curriculum_start_fraction must be in (0, 1], got {self.curriculum_start_fraction}")
        if not 0 <= self.bc_holdout < 1:
            raise ValueError(f"bc_holdout must be in [0, 1), got {self.bc_holdout}")
        if not (0 < self.gamma <= 1 and 0 < self.gae_lambda <= 1 and self.reward_scale > 0):
            raise ValueError("gamma and gae_lambda must be in (0, 1], reward_scale > 0")
        ThresholdConfig(self.anneal_start_t_f_max, self.anneal_start_t_o)  # raises on a bad pair
        self.env_config  # noqa: B018 - EnvConfig validates the task settings
        self.net_config  # noqa: B018 - PolicyNetConfig validates the architecture

    @property
    def env_config(self) -> EnvConfig:
        return EnvConfig(
            coverage_goal=self.coverage_goal,
            max_steps=self.max_steps,
            collision_penalty=self.collision_penalty,
            f1_weight=self.f1_weight,
        )

    @property
    def net_config(self) -> PolicyNetConfig:
        return PolicyNetConfig(
            conv_channels=self.conv_channels,  # type: ignore[arg-type]
            conv_kernels=self.conv_kernels,  # type: ignore[arg-type]
            conv_strides=self.conv_strides,  # type: ignore[arg-type]
            pi_layers=self.pi_layers,
            vf_layers=self.vf_layers,
            input_pool=self.input_pool,
        )

    def curriculum_fraction(self, timesteps: int) -> float:
        """Fraction of the train plans (smallest interior first) PPO episodes are drawn from after ``timesteps``."""
        if self.curriculum_steps == 0:
            return 1.0
        progress = min(1.0, timesteps / self.curriculum_steps)
        return self.curriculum_start_fraction + progress * (1.0 - self.curriculum_start_fraction)

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


def config_from_dict(data: dict, source: str = "<config>") -> PolicyTrainConfig:
    """A config from flat TOML keys; unknown keys, wrong types and bad values are errors naming the key."""
    return toml_config.config_from_dict(PolicyTrainConfig, data, source)


def load_config(path: str | Path) -> PolicyTrainConfig:
    return toml_config.load_toml_config(PolicyTrainConfig, path)


# ---- plans, predictor, environments ------------------------------------------------------------------------------
def load_plans(split: str, count: int) -> list[FloorPlan]:
    """The first ``count`` plans of a generated split (regenerated from the dataset seed, no files needed)."""
    from edge_explorer.world.dataset import regenerate_split

    return regenerate_split(split, count)


def load_predictor(reference: str) -> Predictor:
    """The phase-2 predictor: trained weights (``.safetensors``, torch, one thread) or an export's ``card.json``
    (or its folder), run on the fastest backend available."""
    path = Path(reference)
    if not path.exists():
        raise EdgeExplorerError(f"predictor {reference}: no such file; train/ship the predictor or set phase2_steps=0")
    if path.suffix == ".safetensors":
        from edge_explorer.learn.unet import TorchPredictor

        torch.set_num_threads(1)
        return TorchPredictor.from_file(path)
    from edge_explorer.backends.chain import load_model
    from edge_explorer.predict.predictor import PredictorRuntime

    return PredictorRuntime(load_model(path))


class TrainingWrapper(gym.Wrapper):
    """Scales the reward for learning, reports the episode's collision count in the final ``info`` and draws each
    episode's plan from the curriculum: the ``fraction`` of the env's plans with the smallest interior area."""

    def __init__(self, env: ExplorationEnv, reward_scale: float, seed: int = 0) -> None:
        super().__init__(env)
        self.reward_scale = reward_scale
        self.collisions = 0
        self.rng = np.random.default_rng(seed)  # the curriculum's plan draws (a reset with a seed re-seeds it)
        self.by_area = np.argsort([int(p.interior.sum()) for p in env.plans], kind="stable")
        self.fraction = 1.0

    def set_curriculum(self, fraction: float) -> None:
        """Draw the next episodes' plans from the ``fraction`` smallest (by interior area); 1.0 = all plans."""
        self.fraction = fraction

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self.collisions = 0
        options = dict(options or {})
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        if self.fraction < 1.0 and "plan_index" not in options:
            count = max(1, int(np.ceil(self.fraction * len(self.by_area))))
            options["plan_index"] = int(self.by_area[self.rng.integers(count)])
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.collisions += int(info["collided"])
        info["collisions"] = self.collisions
        info["goal"] = float(terminated)
        return obs, reward * self.reward_scale, terminated, truncated, info


def make_env_fn(
    plans: Sequence[FloorPlan], env_config: EnvConfig, reward_scale: float, predictor: str | None, seed: int
) -> Callable[[], gym.Env]:
    """A picklable factory for ``SubprocVecEnv``: rasterizes the plans in the worker, loads the predictor there."""

    def make() -> gym.Env:
        from stable_baselines3.common.monitor import Monitor

        torch.set_num_threads(1)
        env = ExplorationEnv(
            [plan_to_raster(p) for p in plans], env_config, predictor=load_predictor(predictor) if predictor else None
        )
        env.reset(seed=seed)
        return Monitor(
            TrainingWrapper(env, reward_scale, seed), info_keywords=("coverage", "path_length_m", "collisions", "goal")
        )

    return make


# ---- expert demonstrations ---------------------------------------------------------------------------------------
def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """Σ_k γ^k r_{t+k} for every t of one episode (no bootstrap after its last step)."""
    out = np.zeros(len(rewards), dtype=np.float32)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        out[t] = running
    return out


def fly_expert(plan: FloorPlan, expert: str, env_config: EnvConfig, seed: int) -> dict[str, np.ndarray]:
    """One expert episode from a random start: observations, the expert's actions and the raw rewards."""
    from edge_explorer.plan.baselines import make_planner

    env = ExplorationEnv([plan_to_raster(plan)], env_config)
    planner = make_planner(expert, env.table)
    planner.reset()
    obs, _ = env.reset(seed=seed)
    highs, thres, last, actions, rewards = [], [], [], [], []
    previous = 0
    while True:
        action = planner.act(env.maps, env.pose, previous)
        if action is None:
            break
        highs.append(obs["high"])
        thres.append(obs["thres"])
        last.append(int(np.argmax(obs["last_action"])))
        actions.append(action)
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        previous = 0 if info["collided"] else action
        if terminated or truncated:
            break
    return {
        "high": np.asarray(highs, dtype=np.int8).reshape(-1, *obs["high"].shape),
        "thres": np.asarray(thres, dtype=np.int8).reshape(-1, *obs["thres"].shape),
        "last_action": np.asarray(last, dtype=np.uint8),
        "action": np.asarray(actions, dtype=np.uint8),
        "reward": np.asarray(rewards, dtype=np.float32),
    }


def _single_thread() -> None:
    import cv2

    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def _expert_job(job: tuple[FloorPlan, str, EnvConfig, int, str]) -> int:
    plan, expert, env_config, seed, path = job
    episode = fly_expert(plan, expert, env_config, seed)
    tmp = path + ".tmp.npz"
    np.savez_compressed(tmp, **episode)
    os.replace(tmp, path)
    return len(episode["action"])


def collect_expert(config: PolicyTrainConfig, plans: Sequence[FloorPlan], folder: Path) -> list[Path]:
    """Fly ``expert_episodes`` expert episodes (episode k on plan k mod N, seed derived from k); skip those on disk."""
    from tqdm import tqdm

    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"episode-{k:05d}.npz" for k in range(config.expert_episodes)]
    jobs = [
        (plans[k % len(plans)], config.expert, config.env_config, config.seed * 100_003 + k, str(paths[k]))
        for k in range(config.expert_episodes)
        if not paths[k].exists()
    ]
    if jobs and config.n_envs == 1:
        for job in tqdm(jobs, desc="expert episodes", unit="ep"):
            _expert_job(job)
    elif jobs:
        # fresh interpreters: forking a parent whose opencv/torch thread pools run can deadlock the child
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=config.n_envs, mp_context=context, initializer=_single_thread) as pool:
            for _ in tqdm(pool.map(_expert_job, jobs), total=len(jobs), desc="expert episodes", unit="ep"):
                pass
    return paths


@dataclass
class Demonstrations:
    """Expert steps stacked over episodes; ``episode`` says which episode each step came from."""

    high: np.ndarray
    thres: np.ndarray
    last_action: np.ndarray
    action: np.ndarray
    returns: np.ndarray
    episode: np.ndarray

    @classmethod
    def load(cls, paths: Sequence[Path], gamma: float, reward_scale: float) -> Demonstrations:
        parts: dict[str, list[np.ndarray]] = {k: [] for k in ("high", "thres", "last_action", "action", "returns")}
        episode = []
        for k, path in enumerate(paths):
            with np.load(path) as data:
                if len(data["action"]) == 0:
                    continue
                for key in ("high", "thres", "last_action", "action"):
                    parts[key].append(data[key])
                parts["returns"].append(discounted_returns(data["reward"] * reward_scale, gamma))
                episode.append(np.full(len(data["action"]), k, dtype=np.int32))
        if not episode:
            raise EdgeExplorerError("the expert episodes hold no steps; check the expert and the plans")
        return cls(**{k: np.concatenate(v) for k, v in parts.items()}, episode=np.concatenate(episode))

    def batch(self, index: np.ndarray, device: str) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
        obs = {
            "high": torch.as_tensor(self.high[index], dtype=torch.float32, device=device),
            "thres": torch.as_tensor(self.thres[index], dtype=torch.float32, device=device),
            "last_action": torch.eye(NUM_ACTIONS, device=device)[torch.as_tensor(self.last_action[index]).long()],
        }
        action = torch.as_tensor(self.action[index], device=device).long()
        return obs, action, torch.as_tensor(self.returns[index], device=device)


def behaviour_clone(model: Any, demos: Demonstrations, config: PolicyTrainConfig, log_csv: Path) -> dict:
    """Train the SB3 policy's actor (cross-entropy) and value head (MSE to the expert's returns) on ``demos``."""
    from tqdm import tqdm

    policy = model.policy
    device = str(model.device)
    rng = np.random.default_rng(config.seed)
    episodes = np.unique(demos.episode)
    held = rng.choice(episodes, size=int(round(config.bc_holdout * len(episodes))), replace=False)
    is_held = np.isin(demos.episode, held)
    train_idx, held_idx = np.flatnonzero(~is_held), np.flatnonzero(is_held)
    optimizer = torch.optim.Adam(policy.parameters(), lr=config.bc_learning_rate)
    result: dict[str, Any] = {"train_steps": len(train_idx), "held_out_steps": len(held_idx)}
    for epoch in range(config.bc_epochs):
        policy.train()
        order = rng.permutation(train_idx)
        losses = []
        batches = range(0, len(order), config.bc_batch_size)
        for start in tqdm(batches, desc=f"bc epoch {epoch + 1}/{config.bc_epochs}", unit="batch", leave=False):
            obs, action, returns = demos.batch(order[start : start + config.bc_batch_size], device)
            values, log_prob, _ = policy.evaluate_actions(obs, action)
            actor_loss = -log_prob.mean()
            loss = actor_loss + config.bc_value_weight * torch.nn.functional.mse_loss(values.flatten(), returns)
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), config.max_grad_norm)
            optimizer.step()
            losses.append(actor_loss.item())
        row = {"epoch": epoch + 1, "train_nll": float(np.mean(losses)), **_bc_accuracy(policy, demos, held_idx, device)}
        append_csv_row(log_csv, row)
        result.update(row)
    policy.set_training_mode(False)
    return result


@torch.no_grad()
def _bc_accuracy(policy: Any, demos: Demonstrations, index: np.ndarray, device: str) -> dict:
    """Held-out NLL and argmax agreement with the expert."""
    if len(index) == 0:
        return {"held_out_nll": None, "held_out_accuracy": None}
    policy.set_training_mode(False)
    nll, hits = 0.0, 0
    for start in range(0, len(index), 128):
        obs, action, _ = demos.batch(index[start : start + 128], device)
        dist = policy.get_distribution(obs).distribution
        nll -= float(dist.log_prob(action).sum())
        hits += int((dist.logits.argmax(1) == action).sum())
    return {"held_out_nll": nll / len(index), "held_out_accuracy": hits / len(index)}


# ---- evaluation on val plans -------------------------------------------------------------------------------------
def evaluate(policy: Any, rasters: Sequence[Any], config: PolicyTrainConfig, predictor: Predictor | None) -> dict:
    """The deterministic policy flies ``eval_episodes`` episodes on ``rasters`` (episode k: plan k mod N, fixed seed):
    success (coverage goal without a collision), path length of the successes, coverage, collisions."""
    env = ExplorationEnv(list(rasters), config.env_config, predictor=predictor)
    policy.set_training_mode(False)
    episodes = []
    for k in range(config.eval_episodes):
        obs, _ = env.reset(seed=1_000_000 + k, options={"plan_index": k % len(rasters)})
        collisions, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            action, _ = policy.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(int(action))
            collisions += int(info["collided"])
        episodes.append((terminated, collisions, info["path_length_m"], info["coverage"], info["steps"]))
    goal = np.array([e[0] for e in episodes])
    collisions = np.array([e[1] for e in episodes])
    success = goal & (collisions == 0)
    paths = np.array([e[2] for e in episodes])
    return {
        "episodes": len(episodes),
        "success_rate": float(success.mean()),
        "goal_rate": float(goal.mean()),
        "mean_path_success_m": float(paths[success].mean()) if success.any() else None,
        "mean_coverage": float(np.mean([e[3] for e in episodes])),
        "collisions_per_episode": float(collisions.mean()),
        "mean_steps": float(np.mean([e[4] for e in episodes])),
    }


COLLISION_COST = 0.01  # coverage one collision per episode is worth when picking the best actor


def eval_score(result: dict) -> tuple[float, float, float]:
    """Order of evaluations for picking the best actor: successes, then coverage less ``COLLISION_COST`` per
    collision per episode, then a short path."""
    path = result["mean_path_success_m"]
    safe_coverage = result["mean_coverage"] - COLLISION_COST * result["collisions_per_episode"]
    return (result["success_rate"], round(safe_coverage, 3), -1e9 if path is None else -path)


# ---- run state, logs ---------------------------------------------------------------------------------------------
@dataclass
class RunState:
    stage: str = "expert"
    timesteps: int = 0  # PPO environment steps so far (both phases)
    wall_s: float = 0.0
    best_score: list[float] | None = None
    best_timesteps: int = -1
    best_eval: dict | None = None
    bc: dict | None = None

    def save(self, out: Path) -> None:
        _write_atomically(out / "state.json", json.dumps(dataclasses.asdict(self), indent=1))


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class _Run:
    """What the callbacks share: output folder, state, evaluation plans, the wall-clock budget."""

    def __init__(self, out: Path, config: PolicyTrainConfig, state: RunState, deadline: float | None) -> None:
        self.out, self.config, self.state, self.deadline = out, config, state, deadline
        self.val_rasters = [plan_to_raster(p) for p in load_plans("val", config.val_plans)]
        self.started = time.monotonic()
        self.wall_at_start = state.wall_s
        self.stopped_early = False

    def checkpoint_state(self) -> None:
        self.state.wall_s = self.wall_at_start + time.monotonic() - self.started
        self.state.save(self.out)

    def evaluate(self, model: Any, stage: str, predictor: Predictor | None = None) -> dict:
        result = evaluate(model.policy, self.val_rasters, self.config, predictor)
        row = {"stage": stage, "timesteps": self.state.timesteps, "wall_s": round(self.elapsed(), 1), **result}
        append_csv_row(self.out / "eval.csv", row)
        score = list(eval_score(result))
        metadata = {"stage": stage, "timesteps": str(self.state.timesteps)}
        snapshots = self.out / "evaluated"
        snapshots.mkdir(exist_ok=True)  # every evaluated actor, to pick another one afterwards
        save_policy(model.policy, self.config.net_config, snapshots / f"{stage}-{self.state.timesteps:07d}.safetensors",
                    metadata)  # fmt: skip
        if self.state.best_score is None or score > self.state.best_score:
            self.state.best_score, self.state.best_timesteps, self.state.best_eval = score, self.state.timesteps, row
            save_policy(model.policy, self.config.net_config, self.out / "best.safetensors", metadata)
        return result

    def elapsed(self) -> float:
        return self.wall_at_start + time.monotonic() - self.started


def _callbacks(run: _Run, phase: str, phase_end: int, predictor_ref: str | None) -> list:
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    config = run.config

    class Progress(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=phase_end, initial=self.num_timesteps, desc=phase, unit="step", smoothing=0.05)

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    class Bookkeeping(BaseCallback):
        """Checkpoints, val evaluation, phase-2 annealing and the wall-clock budget, at rollout boundaries."""

        def _on_training_start(self) -> None:
            self.next_checkpoint = self.num_timesteps + config.checkpoint_every_steps
            self.next_eval = self.num_timesteps + config.eval_every_steps
            self.predictor = load_predictor(predictor_ref) if predictor_ref else None
            self._anneal()
            self._curriculum()

        def _on_step(self) -> bool:
            return not run.stopped_early  # False ends learn() before the next rollout is used

        def _curriculum(self) -> None:
            fraction = config.curriculum_fraction(self.num_timesteps)
            self.training_env.env_method("set_curriculum", fraction)
            self.logger.record("train/curriculum_fraction", fraction)

        def _anneal(self) -> None:
            if phase != "phase2":
                return
            start = config.phase1_steps
            progress = min(1.0, max(0.0, (self.num_timesteps - start) / max(config.phase2_steps, 1)))
            final = ThresholdConfig()
            thresholds = ThresholdConfig(
                config.anneal_start_t_f_max + progress * (final.t_f_max - config.anneal_start_t_f_max),
                config.anneal_start_t_o + progress * (final.t_o - config.anneal_start_t_o),
            )
            self.training_env.env_method("set_thresholds", thresholds)
            self.logger.record("train/t_f_max", thresholds.t_f_max)
            self.logger.record("train/t_o", thresholds.t_o)

        def _on_rollout_end(self) -> None:
            run.state.timesteps = self.num_timesteps
            finished = list(self.model.ep_info_buffer)[-20:]  # Monitor's episode ends, info_keywords included
            for key in ("coverage", "goal", "collisions", "path_length_m"):
                if finished:
                    self.logger.record(f"rollout/{key}", float(np.mean([e[key] for e in finished])))
            self._anneal()
            self._curriculum()
            if self.num_timesteps >= self.next_eval:
                self.next_eval += config.eval_every_steps
                result = run.evaluate(self.model, phase, self.predictor)
                for key in ("success_rate", "mean_coverage", "mean_path_success_m", "collisions_per_episode"):
                    if result[key] is not None:
                        self.logger.record(f"eval/{key}", result[key])
            if self.num_timesteps >= self.next_checkpoint:
                self.next_checkpoint += config.checkpoint_every_steps
                save_checkpoint(run, self.model)
            if run.deadline is not None and time.monotonic() >= run.deadline:
                run.stopped_early = True

    return [Progress(), Bookkeeping()]


def save_checkpoint(run: _Run, model: Any) -> None:
    """The SB3 model (policy + optimizer) for --resume, then state.json (last: it never points past the zip)."""
    tmp = run.out / "checkpoint.tmp.zip"
    model.save(tmp)
    os.replace(tmp, run.out / "checkpoint.zip")
    run.state.timesteps = model.num_timesteps
    run.checkpoint_state()


# ---- the run -----------------------------------------------------------------------------------------------------
def train(
    config: PolicyTrainConfig,
    out: str | Path,
    resume: bool = False,
    device: str = "cpu",
    config_path: str | Path | None = None,
    max_minutes: float | None = None,
) -> RunState:
    """Run (or with ``resume`` continue) the stages into ``out``; returns the final state. ``max_minutes`` stops PPO
    at the first rollout boundary after that much wall time of this call (checkpointed; ``--resume`` goes on)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

    out = Path(out)
    if device == "cuda" and not torch.cuda.is_available():
        raise EdgeExplorerError("--device cuda: no CUDA device is available; use --device cpu")
    if config.phase2_steps > 0:
        load_predictor(config.predictor)  # fail now, not after hours of phase 1
    torch.set_num_threads(config.threads)
    set_random_seed(config.seed)
    out.mkdir(parents=True, exist_ok=True)
    saved_config = out / "config.json"
    if resume:
        if not (out / "state.json").exists():
            raise EdgeExplorerError(f"{out}: nothing to resume (no state.json); drop --resume to start a run")
        if config_from_dict(json.loads(saved_config.read_text()), str(saved_config)) != config:
            raise EdgeExplorerError(f"{out}: the run was started with another config ({saved_config}); use that one")
        state = RunState(**json.loads((out / "state.json").read_text()))
        if state.best_eval is not None:  # the rule may have changed since: the next evaluations compare with it
            state.best_score = list(eval_score(state.best_eval))
    elif (out / "state.json").exists():
        raise EdgeExplorerError(f"{out} already holds a run; pass --resume to continue it or choose a new --out")
    else:
        saved_config.write_text(json.dumps(config.to_dict(), indent=1))
        if config_path is not None:
            shutil.copyfile(config_path, out / "config.toml")
        state = RunState()
        state.save(out)
    deadline = None if max_minutes is None else time.monotonic() + 60.0 * max_minutes
    run = _Run(out, config, state, deadline)
    train_plans = load_plans("train", config.train_plans)

    def vec_env(predictor_ref: str | None) -> VecEnv:
        """One worker process per env (forkserver: no forked thread pools); in-process for a single env."""
        fns = [
            make_env_fn(train_plans, config.env_config, config.reward_scale, predictor_ref, config.seed + 7919 * k)
            for k in range(config.n_envs)
        ]
        return SubprocVecEnv(fns, start_method="forkserver") if config.n_envs > 1 else DummyVecEnv(fns)

    def new_model(env: Any) -> Any:
        return PPO(
            "MultiInputPolicy",
            env,
            learning_rate=config.learning_rate,
            n_steps=config.n_steps,
            batch_size=config.batch_size,
            n_epochs=config.n_epochs,
            gamma=config.gamma,
            gae_lambda=config.gae_lambda,
            clip_range=config.clip_range,
            ent_coef=config.ent_coef,
            vf_coef=config.vf_coef,
            max_grad_norm=config.max_grad_norm,
            target_kl=config.target_kl,
            policy_kwargs=sb3_policy_kwargs(config.net_config),
            tensorboard_log=None,
            seed=config.seed,
            device=device,
            verbose=0,
        )

    env = vec_env(None)
    try:
        if state.stage in ("expert", "bc"):
            model = new_model(env)
            if config.expert != "none" and config.expert_episodes > 0:
                paths = collect_expert(config, train_plans, out / "expert")
                state.stage = "bc"
                run.checkpoint_state()
                run.evaluate(model, "init")
                demos = Demonstrations.load(paths, config.gamma, config.reward_scale)
                bc_csv = out / "bc.csv"
                bc_csv.unlink(missing_ok=True)
                state.bc = behaviour_clone(model, demos, config, bc_csv)
                del demos
                run.evaluate(model, "bc")
            state.stage = "phase1"
            save_checkpoint(run, model)
        else:
            model = PPO.load(out / "checkpoint.zip", env=env, device=device)
        if (out / "progress.csv").exists():  # SB3's CSV logger truncates the file: keep the earlier part
            os.replace(out / "progress.csv", out / f"progress-until-{model.num_timesteps:07d}.csv")
        model.set_logger(configure(str(out), ["csv", "tensorboard"]))

        for phase, steps_end, predictor_ref in (
            ("phase1", config.phase1_steps, None),
            ("phase2", config.phase1_steps + config.phase2_steps, config.predictor),
        ):
            if state.stage != phase or run.stopped_early:
                continue
            if phase == "phase2" and config.phase2_steps > 0:
                env.close()
                env = vec_env(predictor_ref)
                model.set_env(env)
            remaining = steps_end - model.num_timesteps
            if remaining > 0:
                model.learn(
                    remaining,
                    callback=_callbacks(run, phase, steps_end, predictor_ref if phase == "phase2" else None),
                    reset_num_timesteps=False,
                    progress_bar=False,
                )
            if not run.stopped_early and model.num_timesteps >= steps_end:
                state.stage = STAGES[STAGES.index(phase) + 1]
            save_checkpoint(run, model)
        save_policy(model.policy, config.net_config, out / "last.safetensors", {"timesteps": str(model.num_timesteps)})
        run.checkpoint_state()
    finally:
        env.close()
    return state
