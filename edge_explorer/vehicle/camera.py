"""The depth camera's model, shared by the simulator's renderer (:mod:`edge_explorer.sim.camera`), the voxel fusion
(:mod:`edge_explorer.mapping.voxels`) and the daemon: pinhole intrinsics, the camera pose and its frames, the
RealSense-like depth noise and the stream's limits.

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

import numpy as np

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
