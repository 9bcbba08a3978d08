"""The gymnasium environment (edge_explorer.sim.env)."""

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from edge_explorer.errors import PlanError
from edge_explorer.mapping import ego
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.vehicle.dynamics import Action
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN
from edge_explorer.world.plan import FloorPlan, Rect
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

EXACT = EnvConfig(motion_noise=False)


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def test_passes_the_gymnasium_checker(rooms):
    env = ExplorationEnv([rooms], render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no spec" notices: the env is not registered
        check_env(env)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert set(info) == {
        "coverage",
        "correct_coverage",
        "f1",
        "n_m_m2",
        "path_length_m",
        "collided",
        "penalised",
        "plan",
        "steps",
    }
    image = env.render()
    assert image.ndim == 3 and image.shape[0] == 237 and image.dtype == np.uint8


def test_seeded_episodes_repeat(rooms):
    runs = []
    for _ in range(2):
        env = ExplorationEnv([rooms, rooms])
        obs, _ = env.reset(seed=7)
        trace = [obs["high"].copy()]
        for action in [3, 3, 5, 1, 3, 0, 4]:
            obs, reward, *_ = env.step(action)
            trace += [obs["high"].copy(), reward, env.pose]
        runs.append(trace)
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)


def test_start_pose_is_in_the_configuration_space(rooms):
    env = ExplorationEnv([rooms])
    for seed in range(20):
        env.reset(seed=seed)
        x, y, _ = env.pose
        assert 0.35 <= x <= 3.65 and 0.35 <= y <= 2.65
        assert not (1.7 < x < 2.3 and not 1.0 < y < 2.0)  # not next to the divider wall outside its door


def test_observation_is_the_shared_encoding_of_the_maps(rooms):
    env = ExplorationEnv([rooms])
    env.reset(seed=3)
    for action in [3, 3, 2, 5]:
        obs, *_ = env.step(action)
    maps = env.maps
    x, y, yaw = env.pose
    expected = ego.observation_from_maps(
        maps.high,
        env.thresholded_low,
        0.05,
        0.20,
        tuple(int(v) for v in maps.high_grid.cell_of(x, y)),
        tuple(int(v) for v in maps.low_grid.cell_of(x, y)),
        yaw,
        Action.TURN_LEFT_FORWARD,
    )
    for key in obs:
        np.testing.assert_array_equal(obs[key], expected[key])
    np.testing.assert_array_equal(env.thresholded_low, maps.low)  # phase 1: M_thres is the observed map


def test_free_motion_is_rewarded_by_the_f1_gain(rooms):
    env = ExplorationEnv([rooms], EXACT)
    _, info = env.reset(options={"start_pose": (1.0, 1.0, math.pi / 2)})
    _, reward, terminated, truncated, new = env.step(Action.FORWARD)
    assert env.pose == pytest.approx((1.0, 1.4375, math.pi / 2))
    assert not (new["collided"] or new["penalised"] or terminated or truncated)
    assert reward == pytest.approx(-1 + 100.0 * (new["f1"] - info["f1"]))
    assert new["path_length_m"] == pytest.approx(0.4375)


def test_collision_stops_the_vehicle_and_is_penalised(rooms):
    env = ExplorationEnv([rooms], EXACT)
    env.reset(options={"start_pose": (0.7, 1.5, math.pi)})  # facing the west wall, 0.6 m away
    _, reward, _, _, info = env.step(Action.FORWARD)
    assert info["collided"] and info["penalised"] and reward == -11.0
    assert env.pose == pytest.approx((0.7, 1.5, -math.pi)) and info["path_length_m"] == 0.0  # yaw in [−π, π)


def test_unavoidable_drift_next_step_is_penalised_now(rooms):
    env = ExplorationEnv([rooms], EXACT)
    env.reset(options={"start_pose": (0.85, 1.5, math.pi)})
    _, reward, _, _, info = env.step(Action.FORWARD)  # reaches x = 0.4125, but braking drifts 0.125 m on
    assert env.pose[0] == pytest.approx(0.4125)
    assert info["penalised"] and not info["collided"] and reward == -11.0


def test_episode_end(rooms):
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=0.05))
    env.reset(seed=0)
    assert env.step(Action.HOVER)[2]  # terminated
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=2))
    env.reset(seed=0)
    assert env.step(Action.HOVER)[2:4] == (False, False)
    assert env.step(Action.HOVER)[2:4] == (False, True)  # truncated


def test_a_whole_floor_model_changes_nothing_in_a_building_within_the_envelope(rooms, tmp_path):
    from edge_explorer.backends.chain import load_model
    from edge_explorer.predict.predictor import PredictorRuntime
    from tests.predict.test_predictor import write_predictor_model

    order = ("onnxruntime-cpu",)
    within = write_predictor_model(tmp_path / "predictor", window=ego.PREDICTOR_WINDOW_CELLS)
    # the whole-floor stand-in paints every unseen cell solid: any call to it would show in the maps
    floors = write_predictor_model(tmp_path / "floors", window=ego.PREDICTOR_WINDOW_CELLS, bias=-5.0)
    maps = []
    for beyond in (None, PredictorRuntime(load_model(floors, order))):
        env = ExplorationEnv([rooms], predictor=PredictorRuntime(load_model(within, order), beyond=beyond))
        env.reset(seed=0)
        maps.append([env.step(action)[4]["correct_coverage"] for action in (Action.FORWARD, Action.TURN_LEFT)])
        maps[-1].append(env.thresholded_low.copy())
    assert maps[0][:2] == maps[1][:2]
    np.testing.assert_array_equal(maps[0][2], maps[1][2])


def test_predictor_layer(rooms):
    env = ExplorationEnv([rooms], predictor=lambda window: np.ones(window.shape, dtype=np.float32))
    _, info = env.reset(seed=0)
    assert info["coverage"] == 1.0 and info["f1"] < 1.0  # everything unobserved is predicted occupied
    thres = env.thresholded_low
    observed = env.maps.low
    assert (thres[observed == UNKNOWN] == OCCUPIED).all()
    np.testing.assert_array_equal(thres[observed != UNKNOWN], observed[observed != UNKNOWN])
    assert env.step(Action.HOVER)[2]  # coverage goal reached

    env = ExplorationEnv([rooms], predictor=lambda window: np.full(window.shape, 0.02))
    env.reset(seed=0)
    assert FREE not in env.thresholded_low[env.maps.low == UNKNOWN]  # little observed: t_f ≈ 0
    env.set_thresholds(ThresholdConfig(t_f_max=0.04, max_plan_area_m2=1.0))
    env.step(Action.HOVER)
    assert (env.thresholded_low[env.maps.low == UNKNOWN] == FREE).all()

    env = ExplorationEnv([rooms], predictor=lambda window: np.zeros((3, 3)))
    with pytest.raises(ValueError, match="predictor returned shape"):
        env.reset(seed=0)


@pytest.mark.parametrize("action", [6, -1, 2.5, "3", True, np.array([1, 2])])
def test_unknown_actions_are_refused(rooms, action):
    env = ExplorationEnv([rooms])
    env.reset(seed=0)
    with pytest.raises(gym.error.InvalidAction):
        env.step(action)


def test_bad_input(rooms):
    with pytest.raises(gym.error.ResetNeeded):
        ExplorationEnv([rooms]).step(0)
    env = ExplorationEnv([rooms])
    with pytest.raises(ValueError, match="reachable flight space"):
        env.reset(options={"start_pose": (2.0, 0.5, 0.0)})  # inside the divider wall
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"start": 1})
    with pytest.raises(ValueError, match="plan_index"):
        env.reset(options={"plan_index": 3})
    with pytest.raises(ValueError, match="at least one plan"):
        ExplorationEnv([])
    with pytest.raises(PlanError, match="0.05"):
        ExplorationEnv([rasterize(two_room_plan(), 0.20)])
    cupboard = FloorPlan(
        "cupboard",
        ((0, 0), (0.6, 0), (0.6, 0.6), (0, 0.6)),
        (Rect(0, 0, 0.6, 0.1), Rect(0, 0.5, 0.6, 0.6), Rect(0, 0, 0.1, 0.6), Rect(0.5, 0, 0.6, 0.6)),
    )
    with pytest.raises(PlanError, match="nowhere to start"):
        ExplorationEnv([rasterize(cupboard, 0.05)]).reset(seed=0)
    with pytest.raises(ValueError, match="coverage_goal"):
        EnvConfig(coverage_goal=0.0)
