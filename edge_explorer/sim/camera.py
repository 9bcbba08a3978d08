"""Simulated depth camera: renders RealSense-D435-like depth frames from a building's 3-D height map.

The world is the 2.5-D extrusion of :class:`~edge_explorer.world.raster.PlanRaster`: a floor plane at z = 0, a
ceiling plane at ``ceiling_height_m``, and each 0.05 m cell a vertical box from the floor up to ``height_m`` (walls
reach the ceiling, tall and low furniture their own height). A ray hits a cell's box where its height at that
point is below the cell's top: on a side face when it enters the cell low enough, on the top face when it comes
down onto it.

The camera's model — intrinsics, the camera pose and its frames (docs/design.md §3), depth noise, the stream's
limits — is :mod:`edge_explorer.vehicle.camera`; depth is z-depth in metres, 0 = no return.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy import ndimage

from edge_explorer.vehicle.camera import CameraConfig, CameraPose
from edge_explorer.world.raster import PlanRaster


class DepthCamera:
    """Renders depth frames of one building. Construction copies the height map once; ``render`` is ~ms."""

    def __init__(self, raster: PlanRaster, config: CameraConfig = CameraConfig()) -> None:  # noqa: B008 (frozen)
        self.raster = raster
        self.config = config
        self._height = np.ascontiguousarray(raster.height_m, dtype=np.float32)
        # Chessboard distance (in cells) from each cell to the nearest cell with an obstacle: rays leap across
        # the empty square around a cell instead of stepping through it cell by cell.
        self._empty_radius = ndimage.distance_transform_cdt(self._height <= 0, metric="chessboard").astype(np.int32)
        self._xn, self._yn = config.intrinsics.normalized_coords()

    def render(self, pose: CameraPose, rng: np.random.Generator | None = None) -> np.ndarray:
        """Depth image (float32, metres, z-depth, 0 = no return) at ``pose``.

        Noise is applied when the config has a noise model and ``rng`` is given; ``rng=None`` renders the exact
        geometry (what tests and ground-truth comparisons want).
        """
        cfg = self.config
        grid = self.raster.grid
        depth = np.zeros(cfg.intrinsics.shape, dtype=np.float32)
        _render_kernel(
            self._height,
            self._empty_radius,
            float(grid.origin_xy[0]),
            float(grid.origin_xy[1]),
            float(grid.resolution_m),
            float(self.raster.ceiling_height_m),
            pose.position_m,
            pose.rotation_map_from_optical(),
            self._xn,
            self._yn,
            float(cfg.min_depth_m),
            float(cfg.max_depth_m),
            depth,
        )
        if cfg.noise is not None and rng is not None:
            depth = cfg.noise.apply(depth, rng, cfg.min_depth_m)
        return depth


@numba.njit(cache=True, nogil=True)
def _render_kernel(height, empty_radius, x0, y0, res, ceiling, cam, rot, xn, yn, min_depth, max_range, out):
    """Cast one ray per pixel: 2-D DDA over the height-map cells, bounded by the floor/ceiling planes.

    In a cell whose nearest obstacle is k ≥ 3 cells away (chessboard), every cell within k − 1 is empty, so the
    ray jumps straight to where it leaves that square.
    """
    rows, cols = height.shape
    cx, cy, cz = cam[0], cam[1], cam[2]
    start_col = int(math.floor((cx - x0) / res))
    start_row = int(math.floor((cy - y0) / res))
    inside = 0 <= start_col < cols and 0 <= start_row < rows
    for v in range(yn.shape[0]):
        for u in range(xn.shape[0]):
            # Unnormalised map-frame direction whose optical z component is 1: the ray parameter is z-depth.
            dx = rot[0, 0] * xn[u] + rot[0, 1] * yn[v] + rot[0, 2]
            dy = rot[1, 0] * xn[u] + rot[1, 1] * yn[v] + rot[1, 2]
            dz = rot[2, 0] * xn[u] + rot[2, 1] * yn[v] + rot[2, 2]
            t_range = max_range / math.sqrt(dx * dx + dy * dy + dz * dz)
            if dz < -1e-12:
                t_plane = -cz / dz
            elif dz > 1e-12:
                t_plane = (ceiling - cz) / dz
            else:
                t_plane = math.inf
            t_end = min(t_plane, t_range)
            t_hit = -1.0
            if inside:
                t_hit = _march(height, empty_radius, x0, y0, res, cx, cy, cz, dx, dy, dz, start_col, start_row, t_end)
            if t_hit < 0.0 and t_plane <= t_range:
                t_hit = t_plane
            out[v, u] = t_hit if t_hit >= min_depth else 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _march(height, empty_radius, x0, y0, res, cx, cy, cz, dx, dy, dz, col, row, t_end):
    """Ray parameter of the first obstacle hit before ``t_end``, or −1."""
    rows, cols = height.shape
    step_c = 1 if dx > 0 else -1
    step_r = 1 if dy > 0 else -1
    inv_dx = 1.0 / dx if dx != 0.0 else math.inf
    inv_dy = 1.0 / dy if dy != 0.0 else math.inf
    inv_res = 1.0 / res
    # Offsets of the cell face the ray leaves through, in cells from the cell's low corner.
    exit_c = 1 if dx > 0 else 0
    exit_r = 1 if dy > 0 else 0
    dt_c = res * abs(inv_dx)
    dt_r = res * abs(inv_dy)
    t_next_c = ((col + exit_c) * res + x0 - cx) * inv_dx
    t_next_r = ((row + exit_r) * res + y0 - cy) * inv_dy
    t_in = 0.0
    while True:
        h = height[row, col]
        if h > 0.0:
            if cz + dz * t_in < h:  # enters the box through a side face (or starts inside it)
                return t_in
            t_out = min(t_next_c, t_next_r, t_end)
            if cz + dz * t_out < h:  # comes down onto the top face
                return (h - cz) / dz
        else:
            k = empty_radius[row, col] - 1
            if k >= 2:
                # Leave the all-empty square [col − k, col + k] × [row − k, row + k] in one step.
                t_c = ((col + step_c * k + exit_c) * res + x0 - cx) * inv_dx
                t_r = ((row + step_r * k + exit_r) * res + y0 - cy) * inv_dy
                if t_c < t_r:
                    t_in = t_c
                    col += step_c * (k + 1)
                    row = min(max(int(math.floor((cy + dy * t_in - y0) * inv_res)), row - k), row + k)
                else:
                    t_in = t_r
                    row += step_r * (k + 1)
                    col = min(max(int(math.floor((cx + dx * t_in - x0) * inv_res)), col - k), col + k)
                if t_in >= t_end or col < 0 or col >= cols or row < 0 or row >= rows:
                    return -1.0
                t_next_c = ((col + exit_c) * res + x0 - cx) * inv_dx
                t_next_r = ((row + exit_r) * res + y0 - cy) * inv_dy
                continue
        if min(t_next_c, t_next_r) >= t_end:
            return -1.0
        if t_next_c < t_next_r:
            col += step_c
            t_in = t_next_c
            t_next_c += dt_c
            if col < 0 or col >= cols:
                return -1.0
        else:
            row += step_r
            t_in = t_next_r
            t_next_r += dt_r
            if row < 0 or row >= rows:
                return -1.0
