"""Planar depth sensor for training: ray casting on the 0.05 m ground-truth grid (docs/design.md §6).

A scan is a fan of rays over the horizontal field of view (default 87°, a depth camera's) from the vehicle's
position, each traversed cell by cell (Amanatides–Woo) up to the range (default 4.5 m): the cells a ray crosses
before it meets an occupied cell are FREE, the occupied cell it meets is OCCUPIED. Rays are spaced so that two
neighbours are less than one cell apart at full range, so no cell inside the field of view is skipped.

Noise, as in the paper: each of the 8 neighbours of a detected occupied cell is also labelled OCCUPIED with a
fixed probability (default 0.1). Optional range noise moves each ray's return along the ray by a Gaussian error
(a return beyond the range is dropped, like a depth camera's invalid pixel). Within one scan an OCCUPIED label
wins over a FREE one. Random numbers come from the caller's ``numpy.random.Generator``, so an episode is
reproducible from its seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from edge_explorer.world.flight_space import VIEW_RANGE_M
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec

RAY_SPACING_CELLS = 0.9  # largest gap between neighbouring rays at full range; < 1 cell so none is skipped


@dataclass(frozen=True)
class SensorConfig:
    """Field of view, range and noise of the planar sensor."""

    fov_rad: float = math.radians(87.0)
    range_m: float = VIEW_RANGE_M  # N_M counts what this range shows from the flight space
    occupied_noise_prob: float = 0.1  # per 8-neighbour of each detected occupied cell
    range_noise_std_m: float = 0.0  # Gaussian error of each ray's return; 0 = off

    def __post_init__(self) -> None:
        if not 0 < self.fov_rad < 2 * math.pi:
            raise ValueError(f"fov_rad must be in (0, 2π), got {self.fov_rad}")
        if not (self.range_m > 0 and math.isfinite(self.range_m)):
            raise ValueError(f"range_m must be a positive number, got {self.range_m}")
        if not 0 <= self.occupied_noise_prob <= 1:
            raise ValueError(f"occupied_noise_prob must be in [0, 1], got {self.occupied_noise_prob}")
        if not self.range_noise_std_m >= 0:
            raise ValueError(f"range_noise_std_m must be ≥ 0, got {self.range_noise_std_m}")

    @property
    def noisy(self) -> bool:
        return self.occupied_noise_prob > 0 or self.range_noise_std_m > 0


@dataclass(frozen=True)
class ScanPatch:
    """One scan as a window of codes on the grid: cell (0, 0) is grid cell (row0, col0); UNKNOWN = not seen."""

    row0: int
    col0: int
    codes: np.ndarray  # int8

    @property
    def rows(self) -> slice:
        return slice(self.row0, self.row0 + self.codes.shape[0])

    @property
    def cols(self) -> slice:
        return slice(self.col0, self.col0 + self.codes.shape[1])


def ray_count(config: SensorConfig, resolution_m: float) -> int:
    """Rays per scan so that neighbours are at most :data:`RAY_SPACING_CELLS` apart at full range."""
    return int(math.ceil(config.fov_rad * config.range_m / resolution_m / RAY_SPACING_CELLS)) + 1


@njit(cache=True)
def _sector_window(x_c, y_c, yaw_rad, fov_rad, range_c, n_rows, n_cols):
    """Grid rows/cols [r0, r1) × [c0, c1) holding every cell the scan can label (noise neighbours included)."""
    half = 0.5 * fov_rad
    x_lo = x_hi = x_c
    y_lo = y_hi = y_c
    for k in range(6):  # both edges of the fan, then the four axis directions where they lie inside it
        if k < 2:
            angle = yaw_rad - half if k == 0 else yaw_rad + half
        else:
            angle = (k - 2) * 0.5 * math.pi
            if abs((angle - yaw_rad + math.pi) % (2 * math.pi) - math.pi) > half:
                continue
        x = x_c + range_c * math.cos(angle)
        y = y_c + range_c * math.sin(angle)
        x_lo, x_hi = min(x_lo, x), max(x_hi, x)
        y_lo, y_hi = min(y_lo, y), max(y_hi, y)
    r0 = max(int(math.floor(y_lo)) - 2, 0)
    r1 = min(int(math.floor(y_hi)) + 3, n_rows)
    c0 = max(int(math.floor(x_lo)) - 2, 0)
    c1 = min(int(math.floor(x_hi)) + 3, n_cols)
    return r0, r1, c0, c1


@njit(cache=True)
def _trace(occupied, x_c, y_c, dx, dy, range_c, free_limit_c, patch, row0, col0):
    """Walk one ray; mark cells entered before ``free_limit_c`` FREE (never over an OCCUPIED label).

    Returns (row, col, entry distance) of the first occupied cell within range, or (-1, -1, inf).
    """
    n_rows, n_cols = occupied.shape
    i = int(math.floor(y_c))
    j = int(math.floor(x_c))
    step_i = 1 if dy > 0 else -1
    step_j = 1 if dx > 0 else -1
    inf = math.inf
    t_next_x = ((j + (1 if dx > 0 else 0)) - x_c) / dx if dx != 0.0 else inf
    t_next_y = ((i + (1 if dy > 0 else 0)) - y_c) / dy if dy != 0.0 else inf
    t_step_x = abs(1.0 / dx) if dx != 0.0 else inf
    t_step_y = abs(1.0 / dy) if dy != 0.0 else inf
    t = 0.0
    while t < range_c and 0 <= i < n_rows and 0 <= j < n_cols:
        if occupied[i, j]:
            return i, j, t
        if t < free_limit_c and patch[i - row0, j - col0] == UNKNOWN:
            patch[i - row0, j - col0] = FREE
        if t_next_x < t_next_y:
            t = t_next_x
            t_next_x += t_step_x
            j += step_j
        else:
            t = t_next_y
            t_next_y += t_step_y
            i += step_i
    return -1, -1, inf


@njit(cache=True)
def _cast_scan(occupied, x_c, y_c, yaw_rad, fov_rad, range_c, n_rays, neighbour_u, noise_prob, range_err_c):
    """One scan as (patch, row0, col0); see the module docstring for the rules."""
    n_rows, n_cols = occupied.shape
    row0, r1, col0, c1 = _sector_window(x_c, y_c, yaw_rad, fov_rad, range_c, n_rows, n_cols)
    p_rows, p_cols = r1 - row0, c1 - col0
    patch = np.zeros((p_rows, p_cols), np.int8)
    hits_i = np.empty(n_rays, np.int64)
    hits_j = np.empty(n_rays, np.int64)
    n_hits = 0
    use_range_noise = range_err_c.shape[0] > 0
    for k in range(n_rays):
        angle = yaw_rad - 0.5 * fov_rad + fov_rad * k / (n_rays - 1)
        dx = math.cos(angle)
        dy = math.sin(angle)
        if not use_range_noise:
            hi, hj, _ = _trace(occupied, x_c, y_c, dx, dy, range_c, range_c, patch, row0, col0)
        else:
            hi, hj, t_hit = _trace(occupied, x_c, y_c, dx, dy, range_c, -1.0, patch, row0, col0)
            if hi < 0:  # nothing within range: the error cannot create a return
                _trace(occupied, x_c, y_c, dx, dy, range_c, range_c, patch, row0, col0)
                continue
            measured = max(t_hit + range_err_c[k], 0.0)
            if measured > range_c:  # return lost beyond the range: only free space is known
                _trace(occupied, x_c, y_c, dx, dy, range_c, range_c, patch, row0, col0)
                continue
            _trace(occupied, x_c, y_c, dx, dy, range_c, measured, patch, row0, col0)
            hi = int(math.floor(y_c + (measured + 1e-6) * dy))
            hj = int(math.floor(x_c + (measured + 1e-6) * dx))
            if not (0 <= hi < n_rows and 0 <= hj < n_cols):
                continue
        if hi < 0 or patch[hi - row0, hj - col0] == OCCUPIED:
            continue
        patch[hi - row0, hj - col0] = OCCUPIED
        hits_i[n_hits] = hi
        hits_j[n_hits] = hj
        n_hits += 1
    if noise_prob > 0.0:
        for h in range(n_hits):
            n = 0
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    if di == 0 and dj == 0:
                        continue
                    u = neighbour_u[8 * h + n]
                    n += 1
                    pi = hits_i[h] + di - row0
                    pj = hits_j[h] + dj - col0
                    if u < noise_prob and 0 <= pi < p_rows and 0 <= pj < p_cols:
                        patch[pi, pj] = OCCUPIED
    return patch, row0, col0


def scan(
    occupied: np.ndarray,
    grid: GridSpec,
    x_m: float,
    y_m: float,
    yaw_rad: float,
    config: SensorConfig = SensorConfig(),
    rng: np.random.Generator | None = None,
) -> ScanPatch:
    """One scan of the ground truth ``occupied`` (bool, on ``grid``) from pose (x_m, y_m, yaw_rad).

    ``rng`` draws the noise; it is required when ``config`` has noise (``SensorConfig(occupied_noise_prob=0.0)``
    scans without). The returned patch covers the sector's bounding box clipped to the grid.
    """
    if config.noisy and rng is None:
        raise ValueError("a noisy SensorConfig needs an rng (numpy.random.Generator)")
    res = grid.resolution_m
    x_c = (x_m - grid.origin_xy[0]) / res
    y_c = (y_m - grid.origin_xy[1]) / res
    if not (0 <= x_c < grid.shape[1] and 0 <= y_c < grid.shape[0]):
        raise ValueError(f"sensor pose ({x_m:.3f}, {y_m:.3f}) m lies outside the grid")
    n_rays = ray_count(config, res)
    if config.occupied_noise_prob > 0:
        neighbour_u = rng.random(8 * n_rays)  # type: ignore[union-attr]
    else:
        neighbour_u = np.empty(0)
    if config.range_noise_std_m > 0:
        range_err_c = rng.normal(0.0, config.range_noise_std_m / res, n_rays)  # type: ignore[union-attr]
    else:
        range_err_c = np.empty(0)
    patch, row0, col0 = _cast_scan(
        occupied,
        x_c,
        y_c,
        float(yaw_rad),
        config.fov_rad,
        config.range_m / res,
        n_rays,
        neighbour_u,
        config.occupied_noise_prob,
        range_err_c,
    )
    return ScanPatch(row0, col0, patch)
