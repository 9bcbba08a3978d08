import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_explorer.plan.trajectory import TrajectoryState, min_jerk_segment

finite = st.floats(-5, 5, allow_nan=False)


@settings(deadline=None)  # behaviour, not timing: a loaded machine must not fail it
@given(st.lists(finite, min_size=12, max_size=12), st.floats(0.2, 3.0))
def test_boundary_conditions_are_met(values, duration_s):
    start = TrajectoryState(np.array(values[0:4]), np.array(values[4:8]) / 5, np.zeros(4))
    end = TrajectoryState(np.array(values[8:12]), np.zeros(4), np.zeros(4))
    seg = min_jerk_segment(start, end, duration_s)
    s0, s1 = seg.state_at(0.0), seg.state_at(duration_s)
    np.testing.assert_allclose(s0.position, start.position, atol=1e-9)
    np.testing.assert_allclose(s0.velocity, start.velocity, atol=1e-9)
    np.testing.assert_allclose(s1.velocity, end.velocity, atol=1e-6)
    np.testing.assert_allclose(s1.acceleration, 0.0, atol=1e-6)
    np.testing.assert_allclose(s1.position[:3], end.position[:3], atol=1e-6)
    # yaw ends on the same angle, reached the short way round
    assert math.cos(s1.position[3] - end.position[3]) == pytest.approx(1.0)
    assert abs(s1.position[3] - s0.position[3]) <= math.pi + 1e-9


def test_rest_to_rest_half_metre_in_one_second_respects_speed_limit():
    seg = min_jerk_segment(TrajectoryState.at_rest(0, 0, 1.7, 0), TrajectoryState.at_rest(0.5, 0, 1.7, 0), 1.0)
    assert seg.peak_speed_m_s() == pytest.approx(0.9375, abs=0.01)  # 15/8 · 0.5 m/s, below v_max = 1 m/s
    positions = seg.sample_positions(0.1)
    assert np.all(np.diff(positions[:, 0]) >= 0)  # no overshoot backwards


def test_yaw_takes_the_short_way():
    seg = min_jerk_segment(
        TrajectoryState.at_rest(0, 0, 0, math.radians(170)), TrajectoryState.at_rest(0, 0, 0, math.radians(-170)), 1.0
    )
    assert seg.state_at(1.0).position[3] == pytest.approx(math.radians(190))


def test_rejects_bad_duration():
    with pytest.raises(ValueError, match="duration_s must be positive"):
        min_jerk_segment(TrajectoryState.at_rest(0, 0, 0, 0), TrajectoryState.at_rest(1, 0, 0, 0), 0.0)
