"""The policy trainer's environment workers as Ray actors (RLlib's rollout model): a stable-baselines3 ``VecEnv``.

``RayVecEnv(factories, address)`` starts one actor per environment factory anywhere on the Ray cluster (one CPU
each); each actor builds its environment there — for the goal policy that loads the exported predictor inside the
actor, on the actor's own machine — and answers ``reset``/``step``/``env_method`` calls. The learner (PPO's
optimisation) stays in the driver process, as with ``SubprocVecEnv``, whose semantics this copies: ``step`` resets
a finished episode at once and keeps its last observation in ``info["terminal_observation"]``;
``env_method("action_masks")`` is how MaskablePPO reads the masks. All actors step in parallel (one ``ray.get``
over all of them per step). Ray is imported only here and in :mod:`edge_explorer.cluster.ray_tasks`, and only when
a trainer is given ``--ray``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn
from stable_baselines3.common.vec_env.subproc_vec_env import _stack_obs

from edge_explorer.cluster.ray_tasks import connect


class _EnvWorker:
    """The body of one environment actor (wrapped by ``ray.remote`` in :class:`RayVecEnv`)."""

    def __init__(self, factory: Callable[[], gym.Env]) -> None:
        self.env = factory()

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        return self.env.observation_space, self.env.action_space

    def reset(self, seed: int | None, options: dict | None) -> tuple[Any, dict]:
        return self.env.reset(seed=seed, **({"options": options} if options else {}))

    def step(self, action: Any) -> tuple[Any, float, bool, dict, dict]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        done = terminated or truncated
        info["TimeLimit.truncated"] = truncated and not terminated
        reset_info: dict = {}
        if done:
            info["terminal_observation"] = observation
            observation, reset_info = self.env.reset()
        return observation, float(reward), done, info, reset_info

    def call(self, name: str, args: tuple, kwargs: dict) -> Any:
        return self.env.get_wrapper_attr(name)(*args, **kwargs)

    def get(self, name: str) -> Any:
        return self.env.get_wrapper_attr(name)

    def set(self, name: str, value: Any) -> None:
        setattr(self.env, name, value)

    def is_wrapped(self, wrapper_class: type) -> bool:
        from stable_baselines3.common.env_util import is_wrapped

        return is_wrapped(self.env, wrapper_class)

    def close(self) -> None:
        self.env.close()


class RayVecEnv(VecEnv):
    """One Ray actor per environment; see the module docstring."""

    def __init__(self, factories: Sequence[Callable[[], gym.Env]], address: str = "auto") -> None:
        self._ray, self._owned = connect(address)
        actor = self._ray.remote(num_cpus=1)(_EnvWorker)
        self._actors = [actor.remote(factory) for factory in factories]
        self._pending: list[Any] | None = None
        observation_space, action_space = self._ray.get(self._actors[0].spaces.remote())
        super().__init__(len(self._actors), observation_space, action_space)

    def reset(self) -> VecEnvObs:
        calls = [a.reset.remote(self._seeds[k], self._options[k]) for k, a in enumerate(self._actors)]
        observations, self.reset_infos = zip(*self._ray.get(calls), strict=True)
        self._reset_seeds()
        self._reset_options()
        return _stack_obs(list(observations), self.observation_space)

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = [a.step.remote(action) for a, action in zip(self._actors, actions, strict=True)]

    def step_wait(self) -> VecEnvStepReturn:
        assert self._pending is not None, "step_async first"
        results = self._ray.get(self._pending)
        self._pending = None
        observations, rewards, dones, infos, self.reset_infos = zip(*results, strict=True)
        return _stack_obs(list(observations), self.observation_space), np.stack(rewards), np.stack(dones), infos

    def close(self) -> None:
        if self._actors:
            self._ray.get([a.close.remote() for a in self._actors])
            for a in self._actors:
                self._ray.kill(a)
            self._actors = []
        if self._owned:
            self._ray.shutdown()

    def env_method(self, method_name: str, *args: Any, indices: VecEnvIndices = None, **kwargs: Any) -> list[Any]:
        return self._ray.get([a.call.remote(method_name, args, kwargs) for a in self._targets(indices)])

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._ray.get([a.get.remote(attr_name) for a in self._targets(indices)])

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._ray.get([a.set.remote(attr_name, value) for a in self._targets(indices)])

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._ray.get([a.is_wrapped.remote(wrapper_class) for a in self._targets(indices)])

    def _targets(self, indices: VecEnvIndices) -> list[Any]:
        return [self._actors[k] for k in self._get_indices(indices)]
