"""Ego-centric transforms, inflation and the observation encoding (edge_explorer.mapping.ego)."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_explorer.mapping import ego
from edge_explorer.vehicle.dynamics import Action
from edge_explorer.world.grid import CELL_DTYPE, FREE, NON_FLIGHT, OCCUPIED, UNKNOWN

codes_maps = st.tuples(st.integers(1, 30), st.integers(1, 30), st.integers(0, 2**32 - 1)).map(
    lambda t: np.random.default_rng(t[2]).integers(-1, 2, size=(t[0], t[1])).astype(CELL_DTYPE)
)


@given(codes=codes_maps, size=st.sampled_from([7, 8, 15, 64]), data=st.data())
def test_pad_shift_then_unshift_returns_the_same_cells(codes, size, data):
    row = data.draw(st.integers(-5, codes.shape[0] + 5))
    col = data.draw(st.integers(-5, codes.shape[1] + 5))
    window = ego.pad_shift(codes, (row, col), size)
    assert window.shape == (size, size) and window.dtype == CELL_DTYPE
    if 0 <= row < codes.shape[0] and 0 <= col < codes.shape[1]:
        assert window[size // 2, size // 2] == codes[row, col]  # the robot's cell is the centre
    back = ego.unshift(window, (row, col), codes.shape, fill=99)
    covered = back != 99
    np.testing.assert_array_equal(back[covered], codes[covered])
    rows, cols = np.nonzero(covered)
    assert np.all(np.abs(rows - row) <= size // 2) and np.all(np.abs(cols - col) <= size // 2)
    if size >= 2 * max(codes.shape) + 12:  # the window covers the whole map: exact inverse
        assert covered.all()


def test_pad_shift_pads_with_unknown_and_unshift_fills_nan():
    codes = np.full((3, 4), OCCUPIED, dtype=CELL_DTYPE)
    window = ego.pad_shift(codes, (0, 0), 4)
    np.testing.assert_array_equal(window[2:, 2:], OCCUPIED)
    assert (window[:2, :] == UNKNOWN).all() and (window[:, :2] == UNKNOWN).all()
    probabilities = ego.unshift(np.full((2, 2), 0.3), (0, 0), (3, 3))
    assert probabilities[0, 0] == 0.3 and np.isnan(probabilities[2, 2])


@given(codes=codes_maps, k=st.integers(-4, 4), size=st.sampled_from([5, 9, 31]), data=st.data())
def test_rotation_is_exact_at_multiples_of_90_degrees(codes, k, size, data):
    center = (data.draw(st.integers(0, codes.shape[0] - 1)), data.draw(st.integers(0, codes.shape[1] - 1)))
    north_up = ego.pad_shift(codes, center, size)
    rotated = ego.rotate_crop(codes, center, math.pi / 2 + k * math.pi / 2, size)
    np.testing.assert_array_equal(rotated, np.rot90(north_up, k))
    np.testing.assert_array_equal(np.rot90(rotated, -k), north_up)  # and back: the same cells


def test_heading_points_along_plus_row_and_right_along_plus_col():
    codes = np.zeros((41, 41), dtype=CELL_DTYPE)
    codes[20, 30] = OCCUPIED  # 10 cells east (+x) of the robot at (20, 20)
    codes[30, 20] = FREE  # 10 cells north (+y)
    window = ego.rotate_crop(codes, (20, 20), 0.0, 21)  # facing east
    assert window[20, 10] == OCCUPIED  # ahead: +row
    assert window[10, 0] == FREE  # north is on the left of an east-facing vehicle: −col


@settings(max_examples=200)
@given(
    yaw=st.floats(-10, 10),
    point=st.tuples(st.floats(-300, 300), st.floats(-300, 300)),
    center=st.tuples(st.integers(-50, 500), st.integers(-50, 500)),
)
def test_point_transform_inverse_for_any_angle(yaw, point, center):
    ego_rc = ego.map_to_ego_cells(np.array(point), center, yaw)
    back = ego.ego_to_map_cells(ego_rc, center, yaw)
    np.testing.assert_allclose(back, point, atol=1e-9)
    # the transform is a rotation: distances to the robot's cell are kept
    d_map = math.hypot(point[0] - center[0], point[1] - center[1])
    d_ego = math.hypot(ego_rc[0] - 118, ego_rc[1] - 118)
    assert d_map == pytest.approx(d_ego, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(codes=codes_maps, yaw=st.floats(-4, 4), data=st.data())
def test_rotate_crop_takes_the_nearest_map_cell(codes, yaw, data):
    center = (data.draw(st.integers(-3, codes.shape[0] + 3)), data.draw(st.integers(-3, codes.shape[1] + 3)))
    size = 41
    window = ego.rotate_crop(codes, center, yaw, size)
    rows, cols = np.mgrid[0:size, 0:size]
    src = ego.ego_to_map_cells(np.stack([rows, cols], axis=-1), center, yaw, size)
    nearest = np.floor(src + 0.5).astype(int)
    frac = src + 0.5 - np.floor(src + 0.5)
    clear = ((frac > 1e-3) & (frac < 1 - 1e-3)).all(axis=-1)  # away from rounding ties (opencv is fixed-point)
    inside = (nearest[..., 0] >= 0) & (nearest[..., 0] < codes.shape[0])
    inside &= (nearest[..., 1] >= 0) & (nearest[..., 1] < codes.shape[1])
    expected = np.zeros((size, size), dtype=CELL_DTYPE)
    expected[inside] = codes[nearest[inside][:, 0], nearest[inside][:, 1]]
    np.testing.assert_array_equal(window[clear], expected[clear])


@settings(max_examples=30, deadline=None)
@given(codes=codes_maps, yaw=st.floats(-4, 4), data=st.data())
def test_rotate_crop_sub_window_equals_a_full_warp(codes, yaw, data):
    center = (data.draw(st.integers(-40, codes.shape[0] + 40)), data.draw(st.integers(-40, codes.shape[1] + 40)))
    full = cv2.warpAffine(
        codes.view(np.uint8),
        ego._ego_to_map_affine(center, yaw, 237),
        (237, 237),
        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    ).view(CELL_DTYPE)
    # equal away from rounding ties: opencv's fixed-point coordinates of a sub-window and of the full window can
    # round a cell whose source lies on a map-cell boundary to either side
    rows, cols = np.mgrid[0:237, 0:237]
    src = ego.ego_to_map_cells(np.stack([rows, cols], axis=-1), center, yaw, 237)
    frac = src + 0.5 - np.floor(src + 0.5)
    clear = ((frac > 1e-3) & (frac < 1 - 1e-3)).all(axis=-1)
    np.testing.assert_array_equal(ego.rotate_crop(codes, center, yaw)[clear], full[clear])


def test_rotate_crop_rejects_non_codes():
    with pytest.raises(TypeError, match="int8"):
        ego.rotate_crop(np.zeros((4, 4)), (2, 2), 0.0)


def test_inflation_kernel_is_the_robot_disk():
    high = ego.inflation_kernel(0.05, 0.25)
    assert high.shape == (11, 11) and high.sum() == 81 and high[5, 0] == 1 and high[0, 0] == 0
    low = ego.inflation_kernel(0.20, 0.25)
    np.testing.assert_array_equal(low, [[0, 1, 0], [1, 1, 1], [0, 1, 0]])


@settings(max_examples=40, deadline=None)
@given(codes=codes_maps, resolution=st.sampled_from([0.05, 0.10, 0.20]))
def test_inflate_codes_equals_cv2_dilate_with_the_disk(codes, resolution):
    occupied = (codes == OCCUPIED).astype(np.uint8)
    band = cv2.dilate(occupied, ego.inflation_kernel(resolution), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    expected = np.where(occupied == 1, OCCUPIED, np.where(band == 1, NON_FLIGHT, codes)).astype(CELL_DTYPE)
    np.testing.assert_array_equal(ego.inflate_codes(codes, resolution), expected)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), shape=st.tuples(st.integers(1, 25), st.integers(1, 25)))
def test_incremental_inflation_equals_full_inflation(seed, shape):
    rng = np.random.default_rng(seed)
    codes = np.zeros(shape, dtype=CELL_DTYPE)
    inflated = ego.InflatedMap(shape, 0.05)
    for _ in range(4):
        mask = rng.random(shape) < 0.3
        new = rng.integers(-1, 2, size=shape).astype(CELL_DTYPE)
        changed = mask & (new != codes)
        codes[changed] = new[changed]
        rows, cols = np.nonzero(changed)
        inflated.update_cells(codes, rows.astype(np.int64), cols.astype(np.int64))
        np.testing.assert_array_equal(inflated.codes, ego.inflate_codes(codes, 0.05))


def test_observation_encoding():
    high = np.zeros((100, 120), dtype=CELL_DTYPE)
    high[40:60, 50:70] = FREE
    high[50, 60] = OCCUPIED
    low = np.zeros((25, 30), dtype=CELL_DTYPE)
    low[12, 15] = OCCUPIED
    obs = ego.observation_from_maps(high, low, 0.05, 0.20, (45, 60), (11, 15), math.pi / 2, Action.FORWARD)
    assert set(obs) == {"high", "thres", "last_action"}
    assert obs["high"].shape == obs["thres"].shape == (237, 237)
    assert obs["high"].dtype == obs["thres"].dtype == CELL_DTYPE
    np.testing.assert_array_equal(obs["last_action"], [0, 0, 0, 1, 0, 0])
    assert obs["last_action"].dtype == np.float32
    assert obs["high"][118 + 5, 118] == OCCUPIED and obs["high"][118 + 5, 118 + 3] == NON_FLIGHT
    assert obs["thres"][119, 118] == OCCUPIED and obs["thres"][118, 118] == NON_FLIGHT
    assert ego.NUM_ACTIONS == len(Action)
    with pytest.raises(ValueError, match="action"):
        ego.one_hot_action(6)
