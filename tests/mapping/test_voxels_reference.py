"""The fast fusion kernel against the straightforward one it replaced: the same maps, voxel for voxel.

:func:`reference_fuse` is the kernel as it was before the speed-up (one ray per point whose end voxel lies outside
the box or out of range, a branch per crossed voxel); the shipped kernel casts one ray per distinct end voxel and
updates without branches. Frames from the daemon's band-limited box, noisy depth, a low pose (most returns below
the box) and returns beyond the range cut exercise every path.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion, depth_to_points
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraConfig, CameraPose, DepthIntrinsics
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


@numba.njit(cache=True)
def reference_fuse(log_odds, stamp, frame, origin, res, points, sensor, max_range, hit, miss, lo, hi):
    ny, nx, nz = log_odds.shape
    lo_flat = log_odds.reshape(-1)
    st_flat = stamp.reshape(-1)
    s = (sensor - origin) / res
    max_range_vox = max_range / res
    targets = np.empty((points.shape[0], 3))
    n_targets = 0
    for k in range(points.shape[0]):
        ix = int(math.floor((points[k, 0] - origin[0]) / res))
        iy = int(math.floor((points[k, 1] - origin[1]) / res))
        iz = int(math.floor((points[k, 2] - origin[2]) / res))
        dx, dy, dz = ix + 0.5 - s[0], iy + 0.5 - s[1], iz + 0.5 - s[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        scale = 1.0
        if dist <= max_range_vox:
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz:
                flat = (iy * nx + ix) * nz + iz
                if st_flat[flat] == frame:
                    continue
                st_flat[flat] = frame
                old = lo_flat[flat]
                lo_flat[flat] = min((0 if old == -32768 else old) + hit, hi)
        else:
            scale = max_range_vox / dist
        targets[n_targets] = (s[0] + dx * scale, s[1] + dy * scale, s[2] + dz * scale)
        n_targets += 1
    for k in range(n_targets):
        p0, p1, p2 = s[0], s[1], s[2]
        d0, d1, d2 = targets[k, 0] - p0, targets[k, 1] - p1, targets[k, 2] - p2
        t_lo, t_hi, inside = 0.0, 1.0, True
        for p, d, n in ((p0, d0, nx), (p1, d1, ny), (p2, d2, nz)):
            if d == 0.0:
                inside = inside and 0.0 <= p < n
            else:
                ta, tb = -p / d, (n - p) / d
                t_lo, t_hi = max(t_lo, min(ta, tb)), min(t_hi, max(ta, tb))
        if not inside or t_lo >= t_hi:
            continue
        ix = min(max(int(math.floor(p0 + d0 * t_lo)), 0), nx - 1)
        iy = min(max(int(math.floor(p1 + d1 * t_lo)), 0), ny - 1)
        iz = min(max(int(math.floor(p2 + d2 * t_lo)), 0), nz - 1)
        e = targets[k]
        n_steps = abs(int(math.floor(e[0])) - ix) + abs(int(math.floor(e[1])) - iy) + abs(int(math.floor(e[2])) - iz)
        sx, out_x = (1, nx) if d0 > 0 else (-1, -1)
        sy, out_y = (1, ny) if d1 > 0 else (-1, -1)
        sz, out_z = (1, nz) if d2 > 0 else (-1, -1)
        tx = ((ix + (1 if d0 > 0 else 0)) - p0) / d0 if d0 != 0.0 else math.inf
        ty = ((iy + (1 if d1 > 0 else 0)) - p1) / d1 if d1 != 0.0 else math.inf
        tz = ((iz + (1 if d2 > 0 else 0)) - p2) / d2 if d2 != 0.0 else math.inf
        dtx = abs(1.0 / d0) if d0 != 0.0 else math.inf
        dty = abs(1.0 / d1) if d1 != 0.0 else math.inf
        dtz = abs(1.0 / d2) if d2 != 0.0 else math.inf
        for _ in range(n_steps):
            flat = (iy * nx + ix) * nz + iz
            if st_flat[flat] != frame:
                st_flat[flat] = frame
                old = lo_flat[flat]
                lo_flat[flat] = max((0 if old == -32768 else old) + miss, lo)
            if tx < ty and tx < tz:
                ix += sx
                if ix == out_x:
                    break
                tx += dtx
            elif ty < tz:
                iy += sy
                if iy == out_y:
                    break
                ty += dty
            else:
                iz += sz
                if iz == out_z:
                    break
                tz += dtz
    return n_targets


@pytest.mark.parametrize("max_range_m", [4.5, 2.0])
def test_fast_kernel_builds_the_reference_maps(max_range_m: float) -> None:
    raster = rasterize(two_room_plan(), 0.05)
    k = DepthIntrinsics(64, 36, 32.0, 32.0, 31.5, 17.5)  # a coarse camera: a few thousand rays a frame
    camera = DepthCamera(raster, CameraConfig(intrinsics=k))
    config = FusionConfig(max_range_m=max_range_m)
    region = VoxelRegion.covering(raster.grid, 1.3, 2.7)  # the daemon's band-limited box
    fast = VoxelMaps(region, config)
    reference = VoxelMaps(region, config)
    hit, miss, lo, hi, _ = config.scaled_logodds()
    rng = np.random.default_rng(0)
    poses = [
        CameraPose(x, y, z, float(yaw))
        for x, y, z in ((1.0, 1.5, 1.7), (3.0, 2.0, 1.0), (2.8, 1.9, 2.2))
        for yaw in np.linspace(0, 2 * math.pi, 5, endpoint=False)
    ]
    for i, pose in enumerate(poses):
        depth = camera.render(pose, rng)
        depth[0, :4] = 0.0  # no-return pixels
        rotation = pose.rotation_map_from_optical()
        fast.fuse(depth, k, pose.position_m, rotation, 0.1 * i)
        points = depth_to_points(depth, k, pose.position_m, rotation, config)
        for vox in (reference.high, reference.low):
            origin = np.asarray(vox.origin_xyz_m)
            reference_fuse(
                vox.log_odds,
                vox._stamp,
                np.uint16(i + 1),
                origin,
                vox.resolution_m,
                points,
                pose.position_m,
                max_range_m,
                hit,
                miss,
                lo,
                hi,
            )
    for grid in ("high", "low"):
        assert np.array_equal(getattr(fast, grid).log_odds, getattr(reference, grid).log_odds), grid
    assert np.count_nonzero(fast.high.log_odds >= 0) > 100  # the frames did map walls
