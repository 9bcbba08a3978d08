"""The planning graph every goal planner searches (shared by the frontier planners and the daemon's waypoint check).

Planning graph (:class:`PlanningGraph`): 8-connected cells of a grid ``factor``× coarser than the 0.05 m map
(default 2: 0.10 m, which keeps at least two cells across the free part of a 0.80 m door; 0.20 m cells can lose
it, and 0.05 m cells make the search four times larger). A planning cell is traversable only if all its fine cells
are observed FREE and at least the robot radius plus the follower's margin from every observed OCCUPIED cell —
:func:`~edge_explorer.world.flight_space.planning_cells`, the rule the plan loaders use on the ground truth to
decide what a flight can reach, so N_M and the planners agree. UNKNOWN is *not* traversable, so a path never
crosses space nobody has seen. An edge costs its length times
``1 + clearance_weight · (shortfall of the clearance below clearance_soft_m) / clearance_soft_m``, so paths keep
away from walls where there is room. Shortest paths come from ``scipy.sparse.csgraph.dijkstra``. The vehicle's
own cell is always a node, so it can leave a spot that sensor noise made look too tight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from edge_explorer.plan.follow import FreeSpace
from edge_explorer.world.flight_space import FLIGHT_CLEARANCE, block_reduce, planning_cells
from edge_explorer.world.grid import GridSpec

# Each undirected 8-neighbour edge once, from its lower node id (row-major) and in order of the other end's id:
# right, then down-left, down and down-right, so each node's edges come out sorted (a canonical CSR row).
_NEIGHBOURS = ((0, 1), (1, -1), (1, 0), (1, 1))
_ESCAPE_RADIUS_M = 1.0  # around a vehicle that stands too close to an obstacle, cells as close count as traversable


@dataclass(frozen=True)
class GraphConfig:
    """Resolution and edge costs of the planning graph."""

    factor: int = FLIGHT_CLEARANCE.planning_factor  # planning cell = factor × factor cells of the 0.05 m map
    clearance_soft_m: float = 0.6  # clearance above which an edge costs only its length
    clearance_weight: float = 2.0

    def __post_init__(self) -> None:
        if self.factor < 1 or self.clearance_soft_m <= 0 or self.clearance_weight < 0:
            raise ValueError("factor must be ≥ 1, clearance_soft_m > 0 and clearance_weight ≥ 0")


@dataclass(frozen=True)
class Traversable:
    """The planning grid: which of its cells the vehicle may cross, and their clearance."""

    grid: GridSpec
    mask: np.ndarray  # bool
    clearance_m: np.ndarray  # float32: the smallest clearance of the cell's fine cells

    @classmethod
    def from_free_space(
        cls,
        free: FreeSpace,
        safe_distance_m: float,
        pose_xy_m: tuple[float, float],
        factor: int,
        unseen_distance_m: float = 0.0,
    ) -> Traversable:
        """Conservative coarsening of ``free`` (see the module docstring). Around the vehicle the follower's escape
        rule applies: if it stands closer to an obstacle than ``safe_distance_m``, cells as close as it is count too,
        so a path out exists; its own cell is always included. With ``unseen_distance_m`` > 0 a cell must also keep
        that far from every UNKNOWN cell — no farther than the vehicle is now — the follower's unseen rule
        (:meth:`~edge_explorer.plan.follow.FreeSpace.unsafe_mask`), so a path leads only where the follower flies."""
        grid = free.grid.coarsened(factor)
        flyable = free.known_free
        if unseen_distance_m > 0:
            here_unseen_m = free.unseen_clearance_at(*pose_xy_m)
            flyable = flyable & (free.unseen_clearance_m >= min(unseen_distance_m, here_unseen_m))
        mask, clearance = planning_cells(flyable, free.clearance_m, safe_distance_m, factor)
        known_free = block_reduce(flyable, factor, np.logical_and, False)
        row, col = (int(v) for v in grid.cell_of(*pose_xy_m))
        if 0 <= row < grid.shape[0] and 0 <= col < grid.shape[1]:
            here_m = free.clearance_at(*pose_xy_m)
            if here_m < safe_distance_m:
                r = int(math.ceil(_ESCAPE_RADIUS_M / grid.resolution_m))
                window = (slice(max(row - r, 0), row + r + 1), slice(max(col - r, 0), col + r + 1))
                mask[window] |= known_free[window] & (clearance[window] >= here_m - grid.resolution_m)
            mask[row, col] = True
        return cls(grid, mask, clearance)

    def contains_path(self, path_xy_m: np.ndarray) -> bool:
        """Every cell of the path but its first (where the vehicle was) is traversable."""
        xy = path_xy_m[1:]
        rows, cols = self.grid.cell_of(xy[:, 0], xy[:, 1])
        return bool(self.grid.contains(rows, cols).all() and self.mask[rows, cols].all())


@dataclass(frozen=True)
class PlanningGraph:
    """Traversable planning cells as a weighted sparse graph; node ids number the traversable cells row-major."""

    grid: GridSpec  # the planning grid
    node_of: np.ndarray  # int64 per planning cell: node id, −1 where not traversable
    cells: np.ndarray  # int64 (N,): flat planning-cell index of each node
    graph: csr_matrix

    @classmethod
    def build(
        cls,
        free: FreeSpace,
        safe_distance_m: float,
        pose_xy_m: tuple[float, float],
        config: GraphConfig,
        unseen_distance_m: float = 0.0,
    ) -> PlanningGraph:
        """The graph of ``free`` (see the module docstring); the cell holding ``pose_xy_m`` is always a node;
        ``unseen_distance_m``: see :meth:`Traversable.from_free_space`."""
        traversable = Traversable.from_free_space(free, safe_distance_m, pose_xy_m, config.factor, unseen_distance_m)
        return cls.from_traversable(traversable, config)

    @classmethod
    def from_traversable(cls, traversable: Traversable, config: GraphConfig) -> PlanningGraph:
        """8-connected graph of the traversable cells, edges weighted as the module docstring says.

        The sparse matrix is written row by row in its canonical form (each edge once, from its lower node id,
        sorted), the matrix a (source, target, weight) list makes once scipy has sorted it, without that list, and in
        float64, which :meth:`search` would otherwise convert it to on every search: on the map of a 110 m stretch of
        a whole floor (the daemon's way home) the build's peak fell from 51 to 33 MB above what it keeps. Two compiled
        passes over the grid write it (count, then fill): a dozen whole-array numpy passes took 8–17 ms of a slow
        daemon decision on a 24 m window."""
        grid = traversable.grid
        node_of = np.full(grid.shape, -1, dtype=np.int64)
        cells = np.flatnonzero(traversable.mask)
        n = len(cells)
        node_of.flat[cells] = np.arange(n)
        shortfall = np.clip(1.0 - traversable.clearance_m / config.clearance_soft_m, 0.0, 1.0)
        penalty = config.clearance_weight * shortfall
        # An edge's weight is computed as numpy computes ``step × (1 + 0.5 (penalty_a + penalty_b))`` on arrays of
        # the penalty's dtype (float32: Python floats take the array's type), so the kernel gets its constants in it.
        constants = np.array([grid.resolution_m, grid.resolution_m * math.sqrt(2.0), 0.5, 1.0], dtype=penalty.dtype)
        index = np.int32 if 4 * n < 2**31 else np.int64  # scipy's own choice for at most 4 n edges
        indptr = np.zeros(n + 1, dtype=index)
        _count_edges(node_of, indptr)
        indices = np.empty(int(indptr[-1]), dtype=index)
        data = np.empty(int(indptr[-1]), dtype=np.float64)  # what Dijkstra searches in: no copy per search
        _fill_edges(node_of, penalty, constants, indices, data)
        graph = csr_matrix((data, indices, indptr), shape=(n, n))
        graph.has_sorted_indices = True
        return cls(grid, node_of, cells, graph)

    def node_at(self, x_m: float, y_m: float) -> int:
        """Node id of the planning cell holding (x_m, y_m), −1 if it is not traversable."""
        row, col = (int(v) for v in self.grid.cell_of(x_m, y_m))
        if not (0 <= row < self.grid.shape[0] and 0 <= col < self.grid.shape[1]):
            return -1
        return int(self.node_of[row, col])

    def search(self, sources: list[int] | np.ndarray, limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """(cost, predecessors) of Dijkstra from each source node: arrays (len(sources), N); nodes costlier than
        ``limit`` are not expanded (cost inf), which keeps a search for something nearby cheap."""
        return dijkstra(self.graph, directed=False, indices=np.asarray(sources), return_predecessors=True, limit=limit)

    def path_xy_m(self, predecessors: np.ndarray, node: int) -> np.ndarray:
        """(K, 2) centres of the cells from the search's source to ``node`` (one row of ``search``'s output)."""
        chain = [node]
        while predecessors[chain[-1]] >= 0:
            chain.append(int(predecessors[chain[-1]]))
        flat = self.cells[np.array(chain[::-1])]
        x, y = self.grid.center_of(*np.divmod(flat, self.grid.shape[1]))
        return np.stack([x, y], axis=1)

    def node_xy_m(self, nodes: np.ndarray) -> np.ndarray:
        """(K, 2) centres of the given nodes' cells."""
        x, y = self.grid.center_of(*np.divmod(self.cells[np.asarray(nodes)], self.grid.shape[1]))
        return np.stack([np.atleast_1d(x), np.atleast_1d(y)], axis=1)


# The 8-neighbour offsets of _NEIGHBOURS, as the kernels' arrays.
_DI = np.array([di for di, _ in _NEIGHBOURS], dtype=np.int64)
_DJ = np.array([dj for _, dj in _NEIGHBOURS], dtype=np.int64)


@numba.njit(cache=True, nogil=True)
def _count_edges(node_of, indptr):
    """indptr[a + 1] ← the edges of nodes 0 … a (each undirected edge once, from its lower node id): a CSR row
    pointer. Nodes are numbered row-major, so the scan meets them in order."""
    rows, cols = node_of.shape
    k = 0
    for i in range(rows):
        for j in range(cols):
            a = node_of[i, j]
            if a < 0:
                continue
            for d in range(4):
                ii, jj = i + _DI[d], j + _DJ[d]
                if ii < rows and 0 <= jj < cols and node_of[ii, jj] >= 0:
                    k += 1
            indptr[a + 1] = k


@numba.njit(cache=True, nogil=True)
def _fill_edges(node_of, penalty, constants, indices, data):
    """Each node's edges in :data:`_NEIGHBOURS` order (ascending target id): the target in ``indices``, the weight
    step × (1 + 0.5 (penalty_a + penalty_b)) in ``data``, computed in ``penalty``'s dtype (``constants``: the
    straight and the diagonal step, 0.5 and 1 in that dtype) and stored as float64."""
    rows, cols = node_of.shape
    half, one = constants[2], constants[3]
    k = 0
    for i in range(rows):
        for j in range(cols):
            if node_of[i, j] < 0:
                continue
            for d in range(4):
                ii, jj = i + _DI[d], j + _DJ[d]
                if ii < rows and 0 <= jj < cols:
                    b = node_of[ii, jj]
                    if b >= 0:
                        step = constants[0] if _DI[d] == 0 or _DJ[d] == 0 else constants[1]
                        indices[k] = b
                        data[k] = step * (one + half * (penalty[i, j] + penalty[ii, jj]))
                        k += 1
