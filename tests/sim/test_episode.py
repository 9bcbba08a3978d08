"""The simulated step loop (edge_explorer.sim.episode)."""

import math

import pytest

from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.sim.episode import Episode, move, previous_after
from edge_explorer.vehicle.dynamics import Action, load_action_table
from edge_explorer.world.raster import configuration_space, rasterize
from tests.conftest import two_room_plan

EXACT = EnvConfig(motion_noise=False, coverage_goal=1.0)
FACING_SOUTH_WALL = {"start_pose": (1.0, 1.5, -math.pi / 2)}  # 1.5 m north of the south wall, heading at it


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


class Scripted:
    """Flies ``actions`` in order, then answers None; records the previous_action it was given each time."""

    def __init__(self, actions):
        self.actions = list(actions)
        self.given = []

    def act(self, maps, pose, previous_action, fused_low=None):
        self.given.append(previous_action)
        return self.actions.pop(0) if self.actions else None


def _episode(rooms, planner, coverage_goal=1.0, max_steps=100):
    env = ExplorationEnv([rooms], EXACT)
    _, info = env.reset(seed=0, options=FACING_SOUTH_WALL)
    return env, Episode(env, planner, info, coverage_goal=coverage_goal, max_steps=max_steps)


def test_a_planner_with_nothing_left_ends_the_episode_as_explored(rooms):
    planner = Scripted([Action.TURN_LEFT, Action.HOVER])
    env, episode = _episode(rooms, planner)
    steps = list(episode.steps())
    assert [s.action for s in steps] == [Action.TURN_LEFT, Action.HOVER]
    assert episode.ending == "explored" and env.maps is not None and episode.info["steps"] == 2
    assert planner.given == [Action.HOVER, Action.TURN_LEFT, Action.HOVER]  # asked once more, answered None


def test_after_a_collision_the_next_previous_action_is_hover(rooms):
    planner = Scripted([Action.FORWARD] * 6)
    _, episode = _episode(rooms, planner)
    steps = list(episode.steps())
    collided = [s.collided for s in steps]
    assert not collided[0] and any(collided)  # it flies into the south wall
    for step, given_next in zip(steps, planner.given[1:], strict=True):
        assert given_next == (Action.HOVER if step.collided else step.action)
    assert episode.collisions == sum(collided) == sum(s.info["collided"] for s in steps)


def test_the_step_cap_and_the_coverage_goal_end_the_episode(rooms):
    planner = Scripted([Action.TURN_LEFT] * 50)
    _, capped = _episode(rooms, planner, max_steps=5)
    assert capped.run() == "step_cap" and capped.info["steps"] == 5 and len(planner.given) == 5
    planner = Scripted([Action.TURN_LEFT] * 50)
    _, reached = _episode(rooms, planner, coverage_goal=1e-6)
    assert reached.run() == "goal" and planner.given == []  # the goal is checked before the planner is asked


def test_an_interrupted_flight_resumes_where_it_stopped(rooms):
    class AsksOnce(Scripted):
        def act(self, maps, pose, previous_action, fused_low=None):
            if len(self.given) == 2 and not hasattr(self, "asked"):
                self.asked = True
                raise LookupError("a question for the caller")
            return super().act(maps, pose, previous_action, fused_low)

    planner = AsksOnce([Action.FORWARD, Action.TURN_RIGHT, Action.TURN_LEFT])
    _, episode = _episode(rooms, planner)
    with pytest.raises(LookupError):
        list(episode.steps())
    assert episode.info["steps"] == 2 and episode.previous == Action.TURN_RIGHT and episode.ending is None
    assert episode.run() == "explored" and episode.info["steps"] == 3


def test_move_stops_at_the_walls(rooms):
    table = load_action_table()
    blocked = ~configuration_space(rooms)
    start = (1.0, 0.4, -math.pi / 2)  # 0.3 m from the south wall, heading at it
    pose, collided = move(table, blocked, rooms.grid, start, Action.FORWARD, Action.FORWARD, None)
    assert collided and pose == start
    pose, collided = move(table, blocked, rooms.grid, start, Action.HOVER, Action.TURN_LEFT, None)
    assert not collided and pose[:2] == pytest.approx(start[:2]) and pose[2] > start[2]
    assert previous_after(Action.FORWARD, True) == Action.HOVER and previous_after(3, False) == 3
