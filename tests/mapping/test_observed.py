"""Two-level observed maps (edge_explorer.mapping.observed)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_explorer.mapping.observed import ObservedMaps, coarsen_codes
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


def _reference_coarsen(high: np.ndarray, factor: int) -> np.ndarray:
    rows, cols = -(-high.shape[0] // factor), -(-high.shape[1] // factor)
    out = np.zeros((rows, cols), dtype=CELL_DTYPE)
    for i in range(rows):
        for j in range(cols):
            block = high[i * factor : (i + 1) * factor, j * factor : (j + 1) * factor]
            out[i, j] = OCCUPIED if (block == OCCUPIED).any() else FREE if (block == FREE).any() else UNKNOWN
    return out


def test_coarsen_rule_by_hand():
    high = np.zeros((4, 6), dtype=CELL_DTYPE)
    high[0, 0] = FREE
    high[1, 1] = OCCUPIED  # block (0, 0): occupied wins over free
    high[3, 4] = FREE  # block (0, 1), cols 4-5 only (6 is not a multiple of 4): free
    np.testing.assert_array_equal(coarsen_codes(high, 4), [[OCCUPIED, FREE]])
    high[0, 5] = FREE
    np.testing.assert_array_equal(coarsen_codes(high, 2), [[OCCUPIED, UNKNOWN, FREE], [UNKNOWN, UNKNOWN, FREE]])
    with pytest.raises(ValueError):
        coarsen_codes(high, 0)


@settings(deadline=None)  # the first example may compile numba kernels
@given(
    seed=st.integers(0, 2**32 - 1), shape=st.tuples(st.integers(1, 19), st.integers(1, 19)), factor=st.integers(1, 5)
)
def test_coarsen_matches_reference(seed, shape, factor):
    high = np.random.default_rng(seed).integers(-1, 2, size=shape).astype(CELL_DTYPE)
    np.testing.assert_array_equal(coarsen_codes(high, factor), _reference_coarsen(high, factor))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_patches_update_high_and_keep_low_derived(seed):
    rng = np.random.default_rng(seed)
    grid = GridSpec((0.0, 0.0), 0.05, (22, 31))  # not a multiple of 4: partial low blocks
    maps = ObservedMaps.empty(grid)
    assert maps.low.shape == (6, 8) and maps.factor == 4
    reference = np.full(grid.shape, np.nan)
    for _ in range(5):
        h, w = int(rng.integers(1, 12)), int(rng.integers(1, 12))
        row0, col0 = int(rng.integers(0, 22 - h + 1)), int(rng.integers(0, 31 - w + 1))
        patch = rng.integers(-1, 2, size=(h, w)).astype(CELL_DTYPE)
        before = maps.high.copy()
        rows, cols = maps.apply_patch(row0, col0, patch)
        # reference: one hit (+847) or miss (−847, the planar sensor's) per known cell, clamped to [−1992, 3476],
        # occupied ≥ 0
        window = reference[row0 : row0 + h, col0 : col0 + w]
        seen = patch != UNKNOWN
        window[seen] = np.clip(np.nan_to_num(window[seen]) + np.where(patch[seen] == OCCUPIED, 847, -847), -1992, 3476)
        expected = np.where(np.isnan(reference), UNKNOWN, np.where(reference >= 0, OCCUPIED, FREE))
        np.testing.assert_array_equal(maps.high, expected)
        changed = np.zeros(grid.shape, dtype=bool)
        changed[rows, cols] = True
        np.testing.assert_array_equal(changed, expected != before)
        np.testing.assert_array_equal(maps.low, coarsen_codes(maps.high, 4))


def test_repeated_evidence_outweighs_one_noisy_hit():
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (4, 4)))
    free, occupied = np.full((1, 1), FREE, CELL_DTYPE), np.full((1, 1), OCCUPIED, CELL_DTYPE)
    maps.apply_patch(0, 0, occupied)
    assert maps.high[0, 0] == OCCUPIED  # a first observation decides on its own
    for _ in range(5):
        maps.apply_patch(0, 0, free)
    assert maps.high[0, 0] == FREE and maps.low[0, 0] == FREE
    maps.apply_patch(0, 0, occupied)  # a noise hit on a cell seen free five times
    assert maps.high[0, 0] == FREE
    for _ in range(3):
        maps.apply_patch(0, 0, occupied)  # a real obstacle keeps being seen
    assert maps.high[0, 0] == OCCUPIED and maps.low[0, 0] == OCCUPIED


def test_a_first_noise_hit_is_undone_by_two_rays_through_the_cell():
    # the planar sensor's neighbour noise marks the free cell in front of a wall occupied in some scans; two later
    # rays through it clear it (with OctoMap's miss of 0.4 it took three, and walls stood a cell thick)
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (4, 4)))
    maps.apply_patch(0, 0, np.full((1, 1), OCCUPIED, CELL_DTYPE))
    maps.apply_patch(0, 0, np.full((1, 1), FREE, CELL_DTYPE))
    assert maps.high[0, 0] == OCCUPIED  # one miss against one hit: still undecided, kept occupied
    maps.apply_patch(0, 0, np.full((1, 1), FREE, CELL_DTYPE))
    assert maps.high[0, 0] == FREE and maps.low[0, 0] == FREE


def test_patch_off_the_map_is_rejected():
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (8, 8)))
    with pytest.raises(ValueError, match="leaves the map"):
        maps.apply_patch(6, 0, np.ones((3, 3), dtype=CELL_DTYPE))


def test_fully_observed_map_matches_low_res_truth():
    raster = rasterize(two_room_plan(), 0.05)
    maps = ObservedMaps.empty(raster.grid)
    maps.apply_patch(0, 0, np.where(raster.occupied, OCCUPIED, FREE).astype(CELL_DTYPE))
    low_truth = raster.coarsened(0.20)
    inside = low_truth.interior
    np.testing.assert_array_equal(maps.low[inside], low_truth.truth_codes()[inside])
    assert maps.observed_area_m2() == pytest.approx(maps.low.size * 0.04)
