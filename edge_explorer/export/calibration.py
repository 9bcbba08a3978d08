"""Calibration and held-back observations, recorded from simulator rollouts on the val split (never from data/).

The val split is regenerated deterministically (:func:`edge_explorer.world.dataset.regenerate_split`), so a recipe's
observations are the same on every machine. Its first ``plans`` plans calibrate the quantizers; the next
``held_back_plans`` plans, never calibrated on, feed the accuracy gates.

* **Predictor**: each plan is explored by a fixed-seed explorer of :mod:`edge_explorer.learn.predictor_flights` (the
  data generator's :func:`~edge_explorer.learn.predictor_data.collect_plan_samples`: partial maps at coverage levels
  drawn uniformly), and each recorded map becomes the network's input exactly as in flight: the north-up ego window
  (:func:`~edge_explorer.mapping.ego.pad_shift`) encoded by :func:`~edge_explorer.predict.encoding.encode_windows`.
  Held-back samples keep their map, robot cell and plan so the gates can threshold and score them.
* **Goal policy**: :class:`~edge_explorer.learn.goal_env.GoalEnv` episodes (one step per goal decision; the recipe's
  predictor filling the fused map, as in phase-2 training), choosing with the fp32 network's masked argmax (10 %
  uniformly random valid goals so episodes differ) or uniformly at random. Every decision is recorded — each
  follows a whole goal flight, so consecutive ones are not near duplicates — up to ``per_plan`` per plan, with
  further episodes on the plan (new seeds, at most :data:`GOAL_EPISODES_PER_PLAN`) when one ends early.
  Held-back decisions keep their valid-goal mask (59 × 59) for the masked-agreement gate.

Observations are feeds: ``{input name: float32 array with a batch of 1}`` in the ONNX (torch) layout.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.export.recipe import CalibrationConfig
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS, pad_shift
from edge_explorer.predict.encoding import encode_windows

Feed = dict[str, np.ndarray]
GOAL_RANDOM_GOAL_PROB = 0.1
GOAL_EPISODES_PER_PLAN = 3


@dataclass(frozen=True)
class MapSample:
    """One held-back predictor observation with what the gates need to threshold and score it."""

    observed_low: np.ndarray  # int8 codes on the plan's 0.20 m grid
    robot_cell: tuple[int, int]
    observed_area_m2: float
    truth_low: np.ndarray
    interior_low: np.ndarray


@dataclass(frozen=True)
class Observations:
    """Calibration feeds, held-back feeds, and what the gates need besides them: (predictor) the held-back maps,
    (goal policy) the held-back valid-goal masks."""

    calibration: list[Feed]
    held_back: list[Feed]
    maps: list[MapSample]
    description: dict
    masks: list[np.ndarray] = field(default_factory=list)  # bool (59, 59) per held-back feed


def val_rasters(config: CalibrationConfig) -> tuple[list, list]:
    """(calibration plans, held-back plans) as 0.05 m rasters of the regenerated val split."""
    from edge_explorer.world.catalog import plan_to_raster
    from edge_explorer.world.dataset import regenerate_split

    plans = regenerate_split(config.split, count=config.plans + config.held_back_plans)
    rasters = [plan_to_raster(p) for p in plans]
    return rasters[: config.plans], rasters[config.plans :]


def _require(feeds: list, what: str, config: CalibrationConfig) -> None:
    if not feeds:
        raise EdgeExplorerError(
            f"the {what} set is empty ({config.plans} + {config.held_back_plans} val plans, {config.per_plan} per "
            "plan gave no observation); raise [calibration] plans / per_plan in the recipe"
        )


def predictor_observations(config: CalibrationConfig, input_name: str) -> Observations:
    """Explore the val plans and record encoded ego windows (see the module docstring)."""
    from edge_explorer.learn.eval_predictor import make_explorer
    from edge_explorer.learn.predictor_data import SampleConfig, collect_plan_samples
    from edge_explorer.learn.predictor_flights import Scene

    calibration_rasters, held_back_rasters = val_rasters(config)
    explorer = make_explorer(config.explorer)
    sample_config = SampleConfig(samples_per_plan=config.per_plan, seed=config.seed)

    def samples(rasters: list, offset: int, desc: str) -> Iterator[tuple[Scene, object]]:
        for k, raster in enumerate(tqdm(rasters, desc=desc, unit="plan")):
            scene = Scene.from_raster(raster)
            rng = np.random.default_rng([config.seed, offset + k])
            for sample in collect_plan_samples(scene, [explorer], rng, sample_config):
                yield scene, sample

    def feed(sample) -> Feed:
        window = pad_shift(sample.observed_low, sample.robot_cell, PREDICTOR_WINDOW_CELLS)
        return {input_name: encode_windows(window)[np.newaxis]}

    calibration = [feed(s) for _, s in samples(calibration_rasters, 0, "calibration rollouts")]
    held_back, maps = [], []
    for scene, s in samples(held_back_rasters, len(calibration_rasters), "held-back rollouts"):
        held_back.append(feed(s))
        maps.append(MapSample(s.observed_low, s.robot_cell, s.observed_area_m2, scene.truth_low, scene.interior_low))
    _require(calibration, "calibration", config)
    _require(held_back, "held-back", config)
    description = _describe(config, calibration_rasters, held_back_rasters, len(calibration), len(held_back))
    return Observations(calibration, held_back, maps, description)


def goal_observations(
    config: CalibrationConfig,
    act: Callable[[dict[str, np.ndarray], np.ndarray], int],
    predictor: Callable[[np.ndarray], np.ndarray] | None,
) -> Observations:
    """Roll the goal env out on the val plans and record every decision with its valid-goal mask; ``act`` maps an
    observation and its flat mask to a valid flat goal cell (see the module docstring)."""
    from edge_explorer.learn.goal_env import GoalEnv
    from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
    from edge_explorer.predict.predictor import thresholds_of
    from edge_explorer.sim.env import EnvConfig

    calibration_rasters, held_back_rasters = val_rasters(config)
    shape = (GOAL_GRID_CELLS, GOAL_GRID_CELLS)

    def rollouts(rasters: list, offset: int, desc: str) -> tuple[list[Feed], list[np.ndarray]]:
        env = GoalEnv(rasters, EnvConfig(thresholds=thresholds_of(predictor)), predictor=predictor)
        feeds: list[Feed] = []
        masks: list[np.ndarray] = []
        for k in tqdm(range(len(rasters)), desc=desc, unit="plan"):
            rng = np.random.default_rng([config.seed, offset + k])
            recorded = 0
            for _ in range(GOAL_EPISODES_PER_PLAN):
                obs, _ = env.reset(seed=int(rng.integers(2**31)), options={"plan_index": k})
                mask = env.action_masks()
                while mask.any() and recorded < config.per_plan:
                    feeds.append({name: np.asarray(v, dtype=np.float32)[np.newaxis] for name, v in obs.items()})
                    masks.append(mask.reshape(shape))
                    recorded += 1
                    explore = config.explorer == "random" or rng.random() < GOAL_RANDOM_GOAL_PROB
                    cell = int(rng.choice(np.flatnonzero(mask))) if explore else act(obs, mask)
                    obs, *_ = env.step(cell)
                    mask = env.action_masks()  # all False once the episode has ended
                if recorded >= config.per_plan:
                    break
        return feeds, masks

    calibration, _ = rollouts(calibration_rasters, 0, "calibration rollouts")
    held_back, masks = rollouts(held_back_rasters, len(calibration_rasters), "held-back rollouts")
    _require(calibration, "calibration", config)
    _require(held_back, "held-back", config)
    description = _describe(config, calibration_rasters, held_back_rasters, len(calibration), len(held_back))
    description["unit"] = "goal decisions of GoalEnv episodes, every decision recorded"
    description["random_goal_share"] = 1.0 if config.explorer == "random" else GOAL_RANDOM_GOAL_PROB
    description["predictor"] = None if config.predictor is None else str(config.predictor)
    return Observations(calibration, held_back, [], description, masks)


def _describe(config: CalibrationConfig, cal: list, held: list, n_cal: int, n_held: int) -> dict:
    return {
        "source": f"simulator rollouts on the regenerated {config.split} split (dataset seed 0)",
        "explorer": config.explorer,
        "seed": config.seed,
        "calibration_plans": [r.name for r in cal],
        "held_back_plans": [r.name for r in held],
        "calibration_observations": n_cal,
        "held_back_observations": n_held,
    }
