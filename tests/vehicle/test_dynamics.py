"""Action dynamics and the shipped action table (edge_explorer.vehicle.dynamics)."""

import json
import math

import numpy as np
import pytest

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import Action, VehicleModel
from edge_explorer.world.grid import GridSpec


@pytest.fixture(scope="module")
def table():
    return dynamics.load_action_table()


def test_shipped_table_equals_the_regenerated_one(tmp_path):
    shipped = json.loads(dynamics.default_table_path().read_text())
    assert shipped == dynamics.action_table_to_dict(dynamics.derive_action_table())
    regenerated = dynamics.write_action_table(tmp_path / "table.json")
    assert regenerated.read_text() == dynamics.default_table_path().read_text()


def test_momentum(table):
    A = Action
    assert table.mean_step(A.FORWARD, A.FORWARD) == pytest.approx((0.5, 0.0, 0.0))
    assert table.mean_step(A.HOVER, A.FORWARD) == pytest.approx((0.4375, 0.0, 0.0))  # must accelerate first
    assert table.mean_step(A.FORWARD, A.HOVER) == pytest.approx((0.125, 0.0, 0.0))  # must brake
    assert table.mean_step(A.HOVER, A.HOVER) == (0.0, 0.0, 0.0)
    assert table.dyaw_rad[A.HOVER, A.TURN_LEFT] == pytest.approx(math.radians(30), abs=1e-6)
    assert table.dyaw_rad[A.TURN_RIGHT, A.TURN_LEFT] == pytest.approx(math.radians(22.5), abs=1e-6)
    dx, dy, dyaw = table.mean_step(A.FORWARD, A.TURN_LEFT_FORWARD)
    assert dy > 0 and dyaw > 0 and 0.45 < math.hypot(dx, dy) <= 0.5  # an arc to the left
    # right is the mirror image of left
    mirror = [0, 2, 1, 3, 5, 4]
    np.testing.assert_allclose(table.dx_body_m, table.dx_body_m[np.ix_(mirror, mirror)], atol=1e-9)
    np.testing.assert_allclose(table.dy_body_m, -table.dy_body_m[np.ix_(mirror, mirror)], atol=1e-9)
    np.testing.assert_allclose(table.dyaw_rad, -table.dyaw_rad[np.ix_(mirror, mirror)], atol=1e-9)
    assert (table.pos_std_m > 0).all() and (table.yaw_std_rad > 0).all()


def test_limits_shape_the_table():
    slow = dynamics.derive_action_table(VehicleModel(accel_max_m_s2=0.5))
    assert slow.dx_body_m[Action.HOVER, Action.FORWARD] < 0.4375
    with pytest.raises(ValueError, match="cruise speed"):
        VehicleModel(forward_step_m=2.0)
    with pytest.raises(ValueError, match="positive"):
        VehicleModel(accel_max_m_s2=0.0)


def test_step_pose_moves_in_the_body_frame(table):
    x, y, yaw = dynamics.step_pose(table, 1.0, 2.0, math.pi / 2, Action.FORWARD, Action.FORWARD)
    assert (x, y, yaw) == pytest.approx((1.0, 2.5, math.pi / 2))
    noisy = [dynamics.step_pose(table, 0, 0, 0, 3, 3, np.random.default_rng(s))[0] for s in range(200)]
    assert np.mean(noisy) == pytest.approx(0.5, abs=0.01) and 0.02 < np.std(noisy) < 0.05
    assert dynamics.wrap_angle_rad(3 * math.pi) == pytest.approx(-math.pi)


def test_swept_path():
    grid = GridSpec((0.0, 0.0), 0.05, (20, 20))
    blocked = np.zeros(grid.shape, dtype=bool)
    blocked[:, 10] = True  # a wall at x ∈ [0.50, 0.55)
    assert not dynamics.swept_path_blocked(blocked, grid, (0.1, 0.1), (0.45, 0.9))
    assert dynamics.swept_path_blocked(blocked, grid, (0.1, 0.1), (0.8, 0.1))
    assert dynamics.swept_path_blocked(blocked, grid, (0.1, 0.1), (0.1, 1.5))  # leaves the grid
    assert dynamics.swept_path_blocked(blocked, grid, (0.52, 0.3), (0.52, 0.3))  # starts inside


def test_bad_table_files(tmp_path):
    bad = tmp_path / "t.json"
    bad.write_text("{")
    with pytest.raises(EdgeExplorerError, match="JSON"):
        dynamics.load_action_table(bad)
    data = dynamics.action_table_to_dict(dynamics.derive_action_table())
    data["dx_body_m"] = data["dx_body_m"][:5]
    bad.write_text(json.dumps(data))
    with pytest.raises(EdgeExplorerError, match="6×6"):
        dynamics.load_action_table(bad)
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(EdgeExplorerError, match="not an action table"):
        dynamics.load_action_table(bad)
    with pytest.raises(EdgeExplorerError, match="cannot read"):
        dynamics.load_action_table(tmp_path / "missing.json")
