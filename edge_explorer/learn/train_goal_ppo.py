"""PPO for the goal policy: sb3-contrib's MaskablePPO on :class:`~edge_explorer.learn.goal_env.GoalEnv`, from BC.

The actor-critic is the :class:`~edge_explorer.learn.goal_net.GoalNet` itself: its spatial action map is the
policy's logits over the 3,481 goal cells and its value head the critic (:class:`GoalActorCritic` plugs the network
in as SB3's features extractor and slices its output, so no layer is added and the trained network exports as is).
Invalid goals are masked by MaskablePPO from ``GoalEnv.action_masks``. The reward is the paper's per decision,
ω·ΔF1(M_thres) − metres flown − l·collisions (the :class:`~edge_explorer.sim.env.EnvConfig`), with the predictor
on (phase 2) or off (phase 1, ``predictor = ""``); ``reward_scale`` only rescales it for learning.

Rollouts run in ``n_envs`` worker processes (SubprocVecEnv; each loads the predictor on its exported backend) over
the first ``train_plans`` plans of the train split — or, with ``ray``, in ``n_envs`` Ray actors anywhere on a
cluster (:class:`~edge_explorer.learn.ray_vec_env.RayVecEnv`; the learner stays in this process). Every
``checkpoint_every`` decisions the SB3 model is saved to
``OUT/checkpoint.zip`` (SB3's format, for ``--resume`` inside runs/ only) and the network to
``OUT/latest.safetensors``; every ``eval_every`` decisions the deterministic policy flies ``eval_plans`` val plans
through the benchmark (:func:`~edge_explorer.sim.episode.run_episode`) and ``OUT/val_log.csv`` records success
and the path at 95 % coverage; the best (most successes, then the shortest mean path) is ``OUT/best.safetensors``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO
from sb3_contrib.common.maskable.policies import MaskableMultiInputActorCriticPolicy
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv
from torch import nn

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.csv_log import append_csv_row
from edge_explorer.learn.goal_env import NUM_GOALS, GoalEnv
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig, load_goal_net, save_goal_net
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig


@dataclass(frozen=True)
class PPOConfig:
    """A PPO run of the goal policy (decisions = environment steps)."""

    init_weights: str = ""  # a GoalNet .safetensors (the BC result); "" = random initialisation
    plans: str = "data/plans"
    train_plans: int = 2000
    val_first: int = 2000  # val plans [val_first, val_first + eval_plans) evaluate the policy
    predictor: str = "models/predictor"  # "" = phase 1 (observed map only)
    n_envs: int = 2
    n_steps: int = 64  # decisions per env per update
    batch_size: int = 32
    n_epochs: int = 4
    learning_rate: float = 1e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.005
    reward_scale: float = 0.05
    total_decisions: int = 20_000
    checkpoint_every: int = 256
    eval_every: int = 1024
    eval_plans: int = 10
    max_steps: int = 1500
    seed: int = 0

    def __post_init__(self) -> None:
        if min(self.n_envs, self.n_steps, self.batch_size, self.n_epochs, self.total_decisions, self.eval_plans) < 1:
            raise EdgeExplorerError("n_envs, n_steps, batch_size, n_epochs, total_decisions, eval_plans must be ≥ 1")


class GoalFeatures(BaseFeaturesExtractor):
    """The whole :class:`GoalNet` as SB3's features extractor: features = [3,481 goal logits, value]."""

    def __init__(self, observation_space: gym.spaces.Dict, net_config: dict[str, Any] | None = None) -> None:
        super().__init__(observation_space, features_dim=NUM_GOALS + 1)
        config = {k: tuple(v) for k, v in (net_config or {}).items()}
        self.net = GoalNet(GoalNetConfig(**config))

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        logits, value = self.net(observations["high"], observations["thres"], observations["last_action"])
        return torch.cat([logits.flatten(1), value[:, None]], dim=1)


class _Columns(nn.Module):
    """Columns [start, stop) of the features: the actor's logits or the critic's value, with no extra layer."""

    def __init__(self, start: int, stop: int) -> None:
        super().__init__()
        self.start, self.stop = start, stop

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return features[:, self.start : self.stop]


class GoalActorCritic(MaskableMultiInputActorCriticPolicy):
    """MaskablePPO's actor-critic whose heads are :class:`GoalFeatures`' own outputs (see the module docstring)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.update(features_extractor_class=GoalFeatures, net_arch=[], ortho_init=False)
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        self.action_net = _Columns(0, NUM_GOALS)
        self.value_net = _Columns(NUM_GOALS, NUM_GOALS + 1)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    @property
    def goal_net(self) -> GoalNet:
        return self.features_extractor.net


class _ScaledReward(gym.Wrapper):
    def __init__(self, env: GoalEnv, scale: float) -> None:
        super().__init__(env)
        self.scale = scale

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return observation, reward * self.scale, terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        return self.env.action_masks()


def _make_env(config: PPOConfig, rank: int):  # noqa: ANN202 - SB3's env factory
    def make() -> gym.Env:
        import cv2

        from edge_explorer.learn.goal_demos import split_rasters
        from edge_explorer.learn.loaders import load_predictor

        cv2.setNumThreads(1)
        torch.set_num_threads(1)
        # each worker its own plans: k ≡ rank (mod n_envs)
        rasters = split_rasters(config.plans, "train", 0, config.train_plans, every=config.n_envs, offset=rank)
        predictor = load_predictor(config.predictor) if config.predictor else None
        env_config = EnvConfig(max_steps=config.max_steps, thresholds=thresholds_of(predictor))
        env = GoalEnv(rasters, env_config, predictor=predictor)
        env.reset(seed=config.seed * 1000 + rank)
        return _ScaledReward(env, config.reward_scale)

    return make


def evaluate(net: GoalNet, config: PPOConfig) -> dict[str, float]:
    """The deterministic policy on ``eval_plans`` val plans through the benchmark: successes and mean path."""
    import copy

    from edge_explorer.learn.goal_demos import split_rasters
    from edge_explorer.learn.goal_net import TorchGoalPolicy
    from edge_explorer.learn.loaders import load_predictor
    from edge_explorer.sim.runs import RunSpec, run_episode
    from edge_explorer.sim.starts import start_pose
    from edge_explorer.world.seeds import run_seed

    predictor = load_predictor(config.predictor) if config.predictor else None
    policy = TorchGoalPolicy(copy.deepcopy(net))
    paths, successes = [], 0
    for raster in split_rasters(config.plans, "val", config.val_first, config.val_first + config.eval_plans):
        spec = RunSpec(
            "drl", raster.name, 0, run_seed(0, raster.name, 0), start_pose(raster, 0), 0.95,
            config.max_steps, config.predictor or None, "eval",
        )  # fmt: skip
        record = run_episode(raster, spec, predictor, policy)
        if record["path_at_coverage_m"] is not None and record["collisions"] == 0:
            successes += 1
            paths.append(record["path_at_coverage_m"])
    return {"successes": successes, "mean_path_m": float(np.mean(paths)) if paths else float("inf")}


class _Progress(BaseCallback):
    """Checkpoints, val evaluations and the best network (see the module docstring)."""

    def __init__(self, out: Path, config: PPOConfig) -> None:
        super().__init__()
        self.out, self.config = out, config
        self.bar: Any = None
        state_path = out / "state.json"
        self.state = json.loads(state_path.read_text()) if state_path.exists() else {"best": [-1, 0.0], "wall_s": 0.0}
        self.started = time.perf_counter() - self.state["wall_s"]

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=self.config.total_decisions, initial=self.model.num_timesteps, desc="goal PPO")

    def _on_step(self) -> bool:
        done = self.model.num_timesteps
        self.bar.update(done - self.bar.n)
        if done % self.config.checkpoint_every < self.training_env.num_envs:
            self._checkpoint()
        if done % self.config.eval_every < self.training_env.num_envs:
            net = self.model.policy.goal_net
            result = evaluate(net, self.config)
            append_csv_row(self.out / "val_log.csv", {"decisions": done, **result, "wall_s": self._wall()})
            score = [result["successes"], -result["mean_path_m"]]
            if score > self.state["best"]:
                self.state["best"] = score
                save_goal_net(net, self.out / "best.safetensors")
        return True

    def _on_training_end(self) -> None:
        self._checkpoint()
        self.bar.close()

    def _wall(self) -> float:
        return time.perf_counter() - self.started

    def _checkpoint(self) -> None:
        self.model.save(self.out / "checkpoint.zip")
        save_goal_net(self.model.policy.goal_net, self.out / "latest.safetensors")
        self.state.update(decisions=self.model.num_timesteps, wall_s=self._wall())
        (self.out / "state.json").write_text(json.dumps(self.state))


def train(config: PPOConfig, out: Path, resume: bool = False, ray: str | None = None) -> int:
    """Run (or with ``resume`` continue) PPO into ``out``, the environments as Ray actors on the cluster at ``ray``
    (``auto`` or a head's address) when given; returns the decisions trained on."""
    if resume != (out / "checkpoint.zip").exists():
        raise EdgeExplorerError(
            f"{out}: nothing to resume (no checkpoint.zip)" if resume else f"{out} already holds a run; use --resume"
        )
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    factories = [_make_env(config, k) for k in range(config.n_envs)]
    if ray is not None:
        from edge_explorer.learn.ray_vec_env import RayVecEnv

        venv = RayVecEnv(factories, ray)
    elif config.n_envs > 1:
        venv = SubprocVecEnv(factories, start_method="spawn")
    else:
        venv = DummyVecEnv(factories)
    try:
        if resume:
            model = MaskablePPO.load(out / "checkpoint.zip", env=venv, device="cpu")
        else:
            (out / "config.json").write_text(json.dumps(asdict(config), indent=1))
            init = load_goal_net(config.init_weights) if config.init_weights else GoalNet()
            model = MaskablePPO(
                GoalActorCritic,
                venv,
                n_steps=config.n_steps,
                batch_size=config.batch_size,
                n_epochs=config.n_epochs,
                learning_rate=config.learning_rate,
                gamma=config.gamma,
                gae_lambda=config.gae_lambda,
                clip_range=config.clip_range,
                ent_coef=config.ent_coef,
                seed=config.seed,
                device="cpu",
                tensorboard_log=str(out),
                policy_kwargs={"features_extractor_kwargs": {"net_config": asdict(init.config)}},
            )
            model.policy.goal_net.load_state_dict(init.state_dict())
        remaining = config.total_decisions - model.num_timesteps
        if remaining > 0:
            model.learn(remaining, callback=_Progress(out, config), reset_num_timesteps=False)
        return int(model.num_timesteps)
    finally:
        venv.close()
