"""Lines of sight: blocked by a cell on the way, not by the target's own cell, the same answers as sampling every
line as one numpy array (the formulation the kernel replaced)."""

from __future__ import annotations

import numpy as np

from edge_explorer.plan.sight import clear_lines
from edge_explorer.world.grid import GridSpec


def _array_reference(origin, delta, t, blocking, grid):
    points = origin + t[None, :, None] * delta[:, None, :]
    rows, cols = grid.cell_of(points[..., 0], points[..., 1])
    rows = np.clip(rows, 0, grid.shape[0] - 1)
    cols = np.clip(cols, 0, grid.shape[1] - 1)
    return ~blocking[rows, cols].any(axis=1)


def test_a_wall_cell_on_the_way_blocks_a_line_and_nothing_else_does():
    grid = GridSpec((0.0, 0.0), 0.2, (10, 10))
    blocking = np.zeros(grid.shape, dtype=bool)
    blocking[5, 5] = True  # centre (1.1, 1.1)
    origin = np.array([0.3, 1.1])
    delta = np.array([[1.6, 0.0], [1.6, 0.6], [0.4, 0.0]])  # through the wall cell, past it, short of it
    t = np.linspace(0.0, 1.0, 18)[:-1]
    assert clear_lines(origin, delta, t, blocking, grid.origin_xy, grid.resolution_m).tolist() == [False, True, True]


def test_lines_answer_as_the_sampled_array_did():
    rng = np.random.default_rng(3)
    for _ in range(20):
        grid = GridSpec((float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5))), 0.2, (30, 40))
        blocking = rng.random(grid.shape) < 0.02
        origin = np.array(grid.origin_xy) + rng.uniform(-0.5, 8.5, 2)  # some samples fall off the grid
        delta = rng.uniform(-3, 3, (200, 2))
        t = np.linspace(0.0, 1.0, 52)[:-1]
        expected = _array_reference(origin, delta, t, blocking, grid)
        got = clear_lines(origin, delta, t, blocking, grid.origin_xy, grid.resolution_m)
        assert got.dtype == bool and np.array_equal(got, expected)
        assert 0 < expected.sum() < len(expected)  # the fixture exercises both answers
