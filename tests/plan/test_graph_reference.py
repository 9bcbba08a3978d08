"""The compiled graph build against the numpy build it replaced: the same sparse matrix, bit for bit.

:func:`reference_graph` is :meth:`PlanningGraph.from_traversable` as it was before the speed-up (whole-array numpy
passes per direction); the shipped build writes the same canonical CSR rows in two compiled passes. Random
traversable masks and clearances (float32, as every caller's, and float64), and the free space of the two-room plan,
give identical row pointers, column indices and weights."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.graph import _NEIGHBOURS, GraphConfig, PlanningGraph, Traversable
from edge_explorer.world.grid import GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


def reference_graph(traversable: Traversable, config: GraphConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, indices, data) as the numpy build wrote them."""
    grid = traversable.grid
    node_of = np.full(grid.shape, -1, dtype=np.int64)
    cells = np.flatnonzero(traversable.mask)
    n = len(cells)
    node_of.flat[cells] = np.arange(n)
    shortfall = np.clip(1.0 - traversable.clearance_m / config.clearance_soft_m, 0.0, 1.0)
    penalty = config.clearance_weight * shortfall
    n_rows, n_cols = grid.shape
    pairs = [
        (
            (slice(0, n_rows - di), slice(max(-dj, 0), n_cols - max(dj, 0))),
            (slice(di, n_rows), slice(max(dj, 0), n_cols - max(-dj, 0))),
        )
        for di, dj in _NEIGHBOURS
    ]
    both = [(node_of[a] >= 0) & (node_of[b] >= 0) for a, b in pairs]
    index = np.int32 if 4 * n < 2**31 else np.int64
    indptr = np.zeros(n + 1, dtype=index)
    for (a, _), edge in zip(pairs, both, strict=True):
        indptr[node_of[a][edge] + 1] += 1
    np.cumsum(indptr, out=indptr)
    slot = indptr[:-1].copy()
    indices = np.empty(int(indptr[-1]), dtype=index)
    data = np.empty(int(indptr[-1]), dtype=np.float64)
    for (di, dj), (a, b), edge in zip(_NEIGHBOURS, pairs, both, strict=True):
        sources = node_of[a][edge]
        at = slot[sources]
        indices[at] = node_of[b][edge]
        step_m = grid.resolution_m * math.hypot(di, dj)
        data[at] = step_m * (1.0 + 0.5 * (penalty[a][edge] + penalty[b][edge]))
        slot[sources] += 1
    return indptr, indices, data


def _assert_same(traversable: Traversable, config: GraphConfig) -> PlanningGraph:
    graph = PlanningGraph.from_traversable(traversable, config)
    indptr, indices, data = reference_graph(traversable, config)
    assert graph.graph.indptr.dtype == indptr.dtype and graph.graph.indices.dtype == indices.dtype
    np.testing.assert_array_equal(graph.graph.indptr, indptr)
    np.testing.assert_array_equal(graph.graph.indices, indices)
    assert graph.graph.data.dtype == np.float64
    assert np.array_equal(graph.graph.data.view(np.int64), data.view(np.int64))  # bit for bit
    return graph


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("seed", range(4))
def test_random_traversables_give_the_reference_matrix(seed: int, dtype: type) -> None:
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 60)), int(rng.integers(1, 60)))
    grid = GridSpec((float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5))), 0.1, shape)
    mask = rng.random(shape) < rng.uniform(0.2, 0.95)
    clearance = rng.uniform(0.0, 1.2, shape).astype(dtype)
    clearance[rng.random(shape) < 0.05] = np.inf
    config = GraphConfig(clearance_soft_m=float(rng.uniform(0.3, 0.9)), clearance_weight=float(rng.uniform(0, 3)))
    _assert_same(Traversable(grid, mask, clearance), config)


def test_no_node_and_one_node() -> None:
    grid = GridSpec((0.0, 0.0), 0.1, (3, 4))
    clearance = np.ones(grid.shape, dtype=np.float32)
    assert _assert_same(Traversable(grid, np.zeros(grid.shape, dtype=bool), clearance), GraphConfig()).graph.nnz == 0
    one = np.zeros(grid.shape, dtype=bool)
    one[2, 3] = True
    assert _assert_same(Traversable(grid, one, clearance), GraphConfig()).graph.shape == (1, 1)


def test_the_two_room_plans_free_space_gives_the_reference_matrix() -> None:
    raster = rasterize(two_room_plan(), 0.05)
    free = FreeSpace.from_codes(raster.truth_codes(), raster.grid)
    traversable = Traversable.from_free_space(free, 0.3, (1.0, 1.0), 2)
    graph = _assert_same(traversable, GraphConfig())
    assert graph.graph.nnz > 1000
