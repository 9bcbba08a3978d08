"""Simulated depth camera: renders RealSense-D435-like depth frames from a building's 3-D height map.

The world is the 2.5-D extrusion of :class:`~edge_explorer.world.raster.PlanRaster`: a floor plane at z = 0, a
ceiling plane at ``ceiling_height_m``, and each 0.05 m cell a vertical box from the floor up to ``height_m`` (walls
reach the ceiling, tall and low furniture their own height). A ray hits a cell's box where its height at that
point is below the cell's top: on a side face when it enters the cell low enough, on the top face when it comes
down onto it.

Frames (docs/design.md §3):

* ``map``: x, y horizontal, z up; yaw counter-clockwise from +x.
* body (FLU, ROS REP 103): x forward, y left, z up. ``R_map_body = Rz(yaw) · Ry(pitch) · Rx(roll)``; positive
  pitch turns about body +y (left), i.e. tilts the nose *down*; positive roll lowers the right side.
* camera optical (RealSense / ROS ``*_optical_frame``): z forward along the optical axis, x right, y down.
  The camera sits at the body origin looking along body +x, so the body→camera transform is the fixed rotation
  :data:`R_BODY_FROM_OPTICAL` (columns: optical x, y, z axes in body coordinates) and zero translation; the
  position of a :class:`CameraPose` is the optical centre.

Depth is z-depth in metres (the RealSense convention: distance along the optical axis, not along the ray);
0 means "no return" (too close, too far, or a dropout), exactly as the driver reports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from edge_explorer.world.raster import PlanRaster

# Columns are the optical frame's x (right), y (down), z (forward) axes written in body FLU coordinates.
R_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

D435_HFOV_RAD = math.radians(87.0)
D435_VFOV_RAD = math.radians(58.0)
D435_NATIVE_PX = (848, 480)
DECIMATED_PX = (212, 120)  # the RealSense decimation filter (factor 4) applied to the native stream


@dataclass(frozen=True)
class DepthIntrinsics:
    """Pinhole intrinsics of a depth stream.

    Pixel (u, v) (column, row) looks along the optical-frame direction ((u − cx)/fx, (v − cy)/fy, 1), so a
    pixel's z-depth is the parameter along that unnormalised direction. With ``cx = (width − 1)/2`` the field
    of view spans the outer pixel *edges*.
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"image size must be positive, got {self.width_px}×{self.height_px}")
        if not (self.fx_px > 0 and self.fy_px > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx_px}, fy={self.fy_px}")

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_rad: float, vfov_rad: float) -> DepthIntrinsics:
        return cls(
            width_px,
            height_px,
            (width_px / 2) / math.tan(hfov_rad / 2),
            (height_px / 2) / math.tan(vfov_rad / 2),
            (width_px - 1) / 2,
            (height_px - 1) / 2,
        )

    @classmethod
    def d435(cls, width_px: int = DECIMATED_PX[0], height_px: int = DECIMATED_PX[1]) -> DepthIntrinsics:
        """D435 depth stream (87° × 58°); default 212×120, the native 848×480 after 4× decimation."""
        return cls.from_fov(width_px, height_px, D435_HFOV_RAD, D435_VFOV_RAD)

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape as numpy sees it: (rows, cols)."""
        return (self.height_px, self.width_px)

    def normalized_coords(self) -> tuple[np.ndarray, np.ndarray]:
        """(x/z per column, y/z per row) of the pixel rays in the optical frame, float64."""
        xn = (np.arange(self.width_px) - self.cx_px) / self.fx_px
        yn = (np.arange(self.height_px) - self.cy_px) / self.fy_px
        return xn, yn


@dataclass(frozen=True)
class CameraPose:
    """Pose of the camera-carrying body in ``map``: optical centre position and FLU attitude (see module doc)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    pitch_rad: float = 0.0
    roll_rad: float = 0.0

    @property
    def position_m(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m], dtype=np.float64)

    def rotation_map_from_optical(self) -> np.ndarray:
        """3×3 rotation taking optical-frame vectors to ``map``: ``R_map_body · R_BODY_FROM_OPTICAL``."""
        return body_rotation(self.yaw_rad, self.pitch_rad, self.roll_rad) @ R_BODY_FROM_OPTICAL


def body_rotation(yaw_rad: float, pitch_rad: float = 0.0, roll_rad: float = 0.0) -> np.ndarray:
    """``R_map_body = Rz(yaw) · Ry(pitch) · Rx(roll)`` for a FLU body."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class DepthNoise:
    """RealSense-like depth errors.

    Stereo depth error grows with the square of depth: σ_z = z² · subpixel / (f · baseline). For the D435 at
    848×480 (f ≈ 447 px, baseline 50 mm, subpixel RMS ≈ 0.08) that is ≈ 0.0036 z²; the 4× decimation filter
    takes the median of each 4×4 block, which roughly halves it, hence the default 0.002 z² (8 mm at 2 m,
    4 cm at 4.5 m). ``dropout_fraction`` of the returns become 0 (holes), as stereo matching failures do.
    """

    sigma_per_m: float = 0.002  # σ_z = sigma_per_m · z²
    dropout_fraction: float = 0.03

    def apply(self, depth_m: np.ndarray, rng: np.random.Generator, min_depth_m: float) -> np.ndarray:
        """A noisy copy of ``depth_m``; returns below ``min_depth_m`` and dropouts become 0."""
        depth = depth_m.astype(np.float32, copy=False)
        noisy = depth + np.float32(self.sigma_per_m) * depth * depth * rng.standard_normal(depth.shape, np.float32)
        keep = (depth > 0) & (noisy >= min_depth_m) & (rng.random(depth.shape, np.float32) >= self.dropout_fraction)
        return np.where(keep, noisy, np.float32(0.0))


@dataclass(frozen=True)
class CameraConfig:
    """Stream geometry and limits. D435 returns nothing closer than ≈ 0.2 m; beyond ``max_depth_m`` we render 0."""

    intrinsics: DepthIntrinsics = DepthIntrinsics.d435()
    min_depth_m: float = 0.2
    max_depth_m: float = 10.0  # Euclidean range along the ray
    noise: DepthNoise | None = DepthNoise()


class DepthCamera:
    """Renders depth frames of one building. Construction copies the height map once; ``render`` is ~ms."""

    def __init__(self, raster: PlanRaster, config: CameraConfig = CameraConfig()) -> None:
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
