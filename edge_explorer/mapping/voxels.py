"""Log-odds voxel fusion of depth frames into two dense local voxel maps (0.05 m and 0.20 m).

This is OctoMap's occupancy model (Hornung et al. 2013) on dense arrays instead of an octree, so one frame costs
milliseconds on one core:

* Per frame, every valid pixel becomes a 3-D point in ``map`` (depth × pixel ray, rotated and translated by the
  camera pose). Zero, NaN and ±inf pixels are skipped: the RealSense driver's "no return" is not free space.
* Endpoint placement (applied to the point cloud itself, so OctoMap fed the same cloud builds the same map): a
  return marks where a surface *begins*, the material lies behind it. Each return's z-depth is extended by
  ``min(k·σ(z) + 1 mm, 7.5 cm)``, σ(z) = 0.002·z² the camera's noise model, k = 4, so the hit lands in the voxel
  behind the surface even when the surface lies exactly on a voxel face (every wall of the grid-snapped plans
  does) and noise scatters half of the returns in front of it — under the hit-wins-per-frame rule below, one
  stray return per frame would grow every such wall by a voxel. The price is a bias away from the camera of
  ≤ 1.9 cm at 1.5 m and ≤ 7.5 cm at long range. ``endpoint_push_sigmas=0, endpoint_push_min_m=0`` gives raw
  OctoMap behaviour (``map bench``, plans A–D: 93.6–95.4 % of observed cells correct instead of ≥ 98.5 %).
* Discretised insert, as OctoMap's ``insertPointCloud(..., discretize=True)``: points are reduced to the set of
  distinct voxels they fall in (inside the box or not: about half of a frame's returns are floor and ceiling points
  below or above the box, and their rays are clipped to it), and one ray is cast from the sensor origin to the
  centre of each such voxel.
  A ray whose target centre lies within ``max_range_m`` (Euclidean) marks the target voxel *occupied* and every
  other voxel it crosses *free*; a longer ray is cut at ``max_range_m`` and only marks free voxels up to the cut
  (OctoMap's ``maxrange``), so far returns clear space without inventing obstacles.
* Each voxel is updated at most once per frame, occupied winning over free (OctoMap's KeySet semantics, which
  keeps surfaces from being erased by grazing rays): all hits of the frame are applied first and stamped with
  the frame number, then the rays' free voxels get one miss each unless already stamped.
* Update: ``L ← clamp(L + logit(p_hit or p_miss), logit(clamp_min), logit(clamp_max))`` with OctoMap's defaults
  p_hit 0.7, p_miss 0.4, clamp 0.12 / 0.97; a voxel is occupied when ``L ≥ logit(occupancy_threshold)`` (0.5),
  free when known and below it. Log-odds are int16 in units of 1/1000 (:data:`LOGODDS_SCALE`);
  :data:`UNKNOWN_LOGODDS` marks never-observed voxels.
* Rays are traversed with the Amanatides–Woo 3-D DDA, clipped to the map's box (a :class:`VoxelRegion`, default
  24 m × 14 m × 3.4 m). Arrays are indexed [row (y), col (x), layer (z)] so rows and columns match a
  :class:`GridSpec`. Voxel coordinates are counted from the region's origin (the *anchor*); a grid whose array
  starts ``offset_cells`` (rows, cols) away from it covers another box of the same lattice, and a ray is traced
  with the same floating-point numbers whatever box it is cast into — :mod:`edge_explorer.mapping.growing` moves
  and grows boxes this way, and what it fuses is bit-for-bit what one large fixed box would hold.

Bad input (shape, dtype, negative depth, NaN pose, time going backwards) raises :class:`FusionInputError`
before anything is written: a rejected frame leaves the maps byte-for-byte unchanged.

Speed (the daemon fuses every frame at 15 Hz): the maps' result does not depend on the order rays are cast in
(each voxel takes one hit if any return ends in it, else one miss if any ray crosses it), so a second ray to the
same end voxel — bit-for-bit the same ray — is skipped; endpoints inside the box are deduplicated with the frame
stamps, the others with a small hash set. Scratch arrays are kept between frames (a fresh 600 kB array costs its
page faults every frame).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from edge_explorer.vehicle.camera import DepthIntrinsics, DepthNoise
from edge_explorer.world.grid import HIGH_RES_M, LOW_RES_M, GridSpec

LOGODDS_SCALE = 1000  # stored int16 value = round(log-odds · LOGODDS_SCALE)
UNKNOWN_LOGODDS = np.iinfo(np.int16).min
_STAMP_WRAP = np.iinfo(np.uint16).max


class FusionInputError(ValueError):
    """A depth frame or pose that cannot be fused; the maps were left untouched."""


def _logit_scaled(p: float) -> int:
    return int(round(math.log(p / (1.0 - p)) * LOGODDS_SCALE))


@dataclass(frozen=True)
class FusionConfig:
    """Sensor model: OctoMap's update parameters (its defaults), the range cut and the endpoint placement."""

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.12
    clamp_max: float = 0.97
    occupancy_threshold: float = 0.5
    max_range_m: float = 4.5
    # Each return's z-depth is extended by min(endpoint_push_sigmas · σ(z) + endpoint_push_min_m,
    # endpoint_push_max_m), σ(z) = depth_sigma_per_m · z² (see the module docstring).
    depth_sigma_per_m: float = DepthNoise().sigma_per_m
    endpoint_push_sigmas: float = 4.0
    endpoint_push_min_m: float = 0.001
    endpoint_push_max_m: float = 0.075

    def __post_init__(self) -> None:
        if not (0.5 < self.prob_hit < 1.0 and 0.0 < self.prob_miss < 0.5):
            raise ValueError(f"need 0.5 < prob_hit < 1 and 0 < prob_miss < 0.5, got {self.prob_hit}, {self.prob_miss}")
        if not (0.0 < self.clamp_min < self.occupancy_threshold < self.clamp_max < 1.0):
            raise ValueError("need 0 < clamp_min < occupancy_threshold < clamp_max < 1")
        if not (self.max_range_m > 0 and math.isfinite(self.max_range_m)):
            raise ValueError(f"max_range_m must be a positive number, got {self.max_range_m}")
        pushes = (self.depth_sigma_per_m, self.endpoint_push_sigmas, self.endpoint_push_min_m, self.endpoint_push_max_m)
        if not all(v >= 0 and math.isfinite(v) for v in pushes):
            raise ValueError("depth_sigma_per_m and the endpoint_push_* settings must be finite and ≥ 0")

    def endpoint_push_m(self, depth_m: float) -> float:
        """How far a return at z-depth ``depth_m`` is extended along its ray (in z-depth)."""
        sigma = self.depth_sigma_per_m * depth_m * depth_m
        return min(self.endpoint_push_sigmas * sigma + self.endpoint_push_min_m, self.endpoint_push_max_m)

    def scaled_logodds(self) -> tuple[int, int, int, int, int]:
        """(hit, miss, clamp_min, clamp_max, threshold) log-odds in int16 units."""
        return (
            _logit_scaled(self.prob_hit),
            _logit_scaled(self.prob_miss),
            _logit_scaled(self.clamp_min),
            _logit_scaled(self.clamp_max),
            _logit_scaled(self.occupancy_threshold),
        )


@dataclass(frozen=True)
class VoxelRegion:
    """The fixed box the maps cover, in ``map``. Its size must be a multiple of both resolutions.

    The xy origin is the origin of the projected 2-D grids; place it on a plan grid's origin (see
    :meth:`covering`) so projected cells line up with ``PlanRaster.truth_codes()`` at 0.05 m and 0.20 m.
    """

    origin_xyz_m: tuple[float, float, float] = (-12.0, -7.0, -0.1)
    size_xyz_m: tuple[float, float, float] = (24.0, 14.0, 3.4)

    @classmethod
    def covering(cls, grid: GridSpec, z_min_m: float = -0.1, z_max_m: float = 3.3) -> VoxelRegion:
        """The region over ``grid`` (same xy origin), its size rounded up to whole 0.20 m cells."""
        w, h = grid.size_xy_m
        up = lambda v: math.ceil(v / LOW_RES_M - 1e-9) * LOW_RES_M  # noqa: E731
        return cls((grid.origin_xy[0], grid.origin_xy[1], z_min_m), (up(w), up(h), up(z_max_m - z_min_m)))

    def shape_at(self, resolution_m: float) -> tuple[int, int, int]:
        """(rows along y, cols along x, layers along z) at ``resolution_m``; raises if the size does not divide."""
        counts = []
        for size in (self.size_xyz_m[1], self.size_xyz_m[0], self.size_xyz_m[2]):
            n = int(round(size / resolution_m))
            if n <= 0 or abs(n * resolution_m - size) > 1e-6:
                raise ValueError(f"region size {self.size_xyz_m} m is not a multiple of {resolution_m} m")
            counts.append(n)
        return (counts[0], counts[1], counts[2])


class VoxelGrid:
    """One dense log-odds voxel map. ``log_odds`` is int16 [row y, col x, layer z]; read it, do not write it.

    A voxel is occupied when ``log_odds >= threshold_logodds``, free when known and below it.
    """

    def __init__(self, region: VoxelRegion, resolution_m: float, threshold_logodds: int = 0) -> None:
        self.region = region
        self.resolution_m = float(resolution_m)
        self.threshold_logodds = int(threshold_logodds)
        self.origin_xyz_m = tuple(float(v) for v in region.origin_xyz_m)
        self.shape = region.shape_at(resolution_m)
        self.log_odds = np.full(self.shape, UNKNOWN_LOGODDS, dtype=np.int16)
        self._stamp = np.zeros(self.shape, dtype=np.uint16)  # frame number of each voxel's last update
        self.offset_cells = (0, 0)  # (row, col) of array element [0, 0] counted from the anchor (origin_xyz_m)

    @property
    def grid(self) -> GridSpec:
        """The 2-D grid of this map's columns (what projection produces)."""
        x0, y0 = (
            o + k * self.resolution_m for o, k in zip(self.origin_xyz_m[:2], self.offset_cells[::-1], strict=True)
        )
        return GridSpec((x0, y0), self.resolution_m, self.shape[:2])

    def reframe(self, row0: int, col0: int, rows: int, cols: int) -> None:
        """Cover anchor cells [row0, row0 + rows) × [col0, col0 + cols) instead: what the two boxes share keeps its
        log-odds, the rest is unknown. Only between frames (the frame stamps are cleared)."""
        old, (r_old, c_old) = self.log_odds, self.offset_cells
        self.log_odds = np.full((rows, cols, self.shape[2]), UNKNOWN_LOGODDS, dtype=np.int16)
        r_lo, r_hi = max(row0, r_old), min(row0 + rows, r_old + old.shape[0])
        c_lo, c_hi = max(col0, c_old), min(col0 + cols, c_old + old.shape[1])
        if r_hi > r_lo and c_hi > c_lo:
            self.log_odds[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = old[
                r_lo - r_old : r_hi - r_old, c_lo - c_old : c_hi - c_old
            ]
        del old
        self._stamp = np.zeros(self.log_odds.shape, dtype=np.uint16)
        self.shape = self.log_odds.shape
        self.offset_cells = (row0, col0)

    def layer_centers_m(self) -> np.ndarray:
        return self.origin_xyz_m[2] + (np.arange(self.shape[2]) + 0.5) * self.resolution_m

    def index_of(self, x_m: float, y_m: float, z_m: float) -> tuple[int, int, int]:
        """(row, col, layer) array index of the voxel containing a ``map`` point (may be out of bounds)."""
        x0, y0, z0 = self.origin_xyz_m
        r = self.resolution_m
        row0, col0 = self.offset_cells
        return (math.floor((y_m - y0) / r) - row0, math.floor((x_m - x0) / r) - col0, math.floor((z_m - z0) / r))


@dataclass(frozen=True)
class FusionStats:
    """What one ``fuse`` call did."""

    points: int  # valid pixels turned into points
    rays_high: int  # distinct endpoint voxels (rays cast) at the high resolution
    rays_low: int


class VoxelMaps:
    """The high-res (0.05 m) and low-res (0.20 m) maps, fused together frame by frame."""

    def __init__(
        self,
        region: VoxelRegion = VoxelRegion(),
        config: FusionConfig = FusionConfig(),
        high_res_m: float = HIGH_RES_M,
        low_res_m: float = LOW_RES_M,
    ) -> None:
        self.region = region
        self.config = config
        self._hit, self._miss, self._lo, self._hi, threshold = config.scaled_logodds()
        self.high = VoxelGrid(region, high_res_m, threshold)
        self.low = VoxelGrid(region, low_res_m, threshold)
        self.last_timestamp_s: float | None = None
        self.frames_fused = 0
        self._frame = 0
        self._scratch: _Scratch | None = None

    def fuse(
        self,
        depth_m: np.ndarray,
        intrinsics: DepthIntrinsics,
        position_m: np.ndarray,
        rotation_map_from_optical: np.ndarray,
        timestamp_s: float,
    ) -> FusionStats:
        """Fuse one depth frame (z-depth metres, float32/float64, shape of ``intrinsics``) taken at a pose.

        ``rotation_map_from_optical`` takes optical-frame vectors (z forward, x right, y down) to ``map``; for a
        body attitude use :meth:`edge_explorer.vehicle.camera.CameraPose.rotation_map_from_optical`. Timestamps must
        not decrease. Raises :class:`FusionInputError` (nothing written) on bad input.
        """
        position, rotation = self._validate(depth_m, intrinsics, position_m, rotation_map_from_optical, timestamp_s)
        if self._scratch is None or self._scratch.points.shape[0] != depth_m.size:
            self._scratch = _Scratch(depth_m.size)
        scratch = self._scratch
        points = scratch.points[: _fill_points(depth_m, intrinsics, position, rotation, self.config, scratch.points)]
        self._frame += 1
        if self._frame >= _STAMP_WRAP:  # stamps are uint16: start a new epoch
            self.high._stamp[...] = 0
            self.low._stamp[...] = 0
            self._frame = 1
        self._before_insert(position)
        rays = []
        for vox in (self.high, self.low):
            rays.append(
                _fuse_kernel(
                    vox.log_odds,
                    vox._stamp,
                    np.uint16(self._frame),
                    np.asarray(vox.origin_xyz_m),
                    vox.resolution_m,
                    vox.offset_cells[0],
                    vox.offset_cells[1],
                    points,
                    position,
                    self.config.max_range_m,
                    self._hit,
                    self._miss,
                    self._lo,
                    self._hi,
                    scratch.targets,
                    scratch.seen_keys,
                    scratch.seen_used,
                )
            )
        self.last_timestamp_s = float(timestamp_s)
        self.frames_fused += 1
        return FusionStats(len(points), rays[0], rays[1])

    def _before_insert(self, position_m: np.ndarray) -> None:
        """Called with a valid frame's camera position before anything is written (a growing map moves here)."""

    def _validate(
        self,
        depth_m: np.ndarray,
        intrinsics: DepthIntrinsics,
        position_m: np.ndarray,
        rotation: np.ndarray,
        timestamp_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        if not isinstance(depth_m, np.ndarray) or depth_m.dtype not in (np.float32, np.float64):
            raise FusionInputError(
                f"depth must be a float32 or float64 array in metres, got {getattr(depth_m, 'dtype', type(depth_m))} "
                "(scale raw uint16 RealSense depth by its depth_scale first)"
            )
        if depth_m.shape != intrinsics.shape:
            raise FusionInputError(f"depth shape {depth_m.shape} does not match the intrinsics {intrinsics.shape}")
        negative = (depth_m < 0) & np.isfinite(depth_m) if (depth_m < 0).any() else None  # ±inf, NaN: no return
        if negative is not None and negative.any():
            raise FusionInputError(
                f"depth has {int(negative.sum())} negative values (min {depth_m[negative].min():.3f} m)"
            )
        try:
            position = np.asarray(position_m, dtype=np.float64)
            rotation = np.asarray(rotation, dtype=np.float64)
            timestamp = float(timestamp_s)
        except (TypeError, ValueError) as exc:
            raise FusionInputError(f"pose and timestamp must be numbers: {exc}") from None
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise FusionInputError(f"camera position must be 3 finite numbers, got {position_m!r}")
        if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)):
            raise FusionInputError("camera rotation must be a finite 3×3 matrix")
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            raise FusionInputError("camera rotation is not a rotation matrix (R·Rᵀ ≠ I or det < 0)")
        if not math.isfinite(timestamp):
            raise FusionInputError(f"timestamp must be finite, got {timestamp_s!r}")
        if self.last_timestamp_s is not None and timestamp < self.last_timestamp_s:
            raise FusionInputError(
                f"timestamp {timestamp:.6f} s is earlier than the last fused frame ({self.last_timestamp_s:.6f} s)"
            )
        return position, rotation


def depth_to_points(
    depth_m: np.ndarray,
    intrinsics: DepthIntrinsics,
    position_m: np.ndarray,
    rotation_map_from_optical: np.ndarray,
    config: FusionConfig = FusionConfig(),
) -> np.ndarray:
    """(N, 3) float64 ``map``-frame endpoints of the finite, positive pixels, in row-major pixel order.

    Each return is extended by ``config.endpoint_push_m(z)``. This is the point cloud that :meth:`VoxelMaps.fuse`
    inserts (and the benchmark hands to OctoMap).
    """
    out = np.empty((depth_m.size, 3), dtype=np.float64)
    return out[: _fill_points(depth_m, intrinsics, position_m, rotation_map_from_optical, config, out)]


def _fill_points(
    depth_m: np.ndarray,
    intrinsics: DepthIntrinsics,
    position_m: np.ndarray,
    rotation_map_from_optical: np.ndarray,
    config: FusionConfig,
    out: np.ndarray,
) -> int:
    """Write :func:`depth_to_points`'s points into the first rows of ``out`` (≥ depth_m.size rows); returns how
    many."""
    xn, yn = _pixel_rays(intrinsics)
    return _points_kernel(
        np.ascontiguousarray(depth_m),
        xn,
        yn,
        np.ascontiguousarray(rotation_map_from_optical, dtype=np.float64),
        np.ascontiguousarray(position_m, dtype=np.float64),
        config.endpoint_push_sigmas * config.depth_sigma_per_m,
        config.endpoint_push_min_m,
        config.endpoint_push_max_m,
        out,
    )


@functools.lru_cache(maxsize=8)
def _pixel_rays(intrinsics: DepthIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """``intrinsics.normalized_coords()``, computed once per camera model."""
    xn, yn = intrinsics.normalized_coords()
    xn.flags.writeable = yn.flags.writeable = False
    return xn, yn


class _Scratch:
    """Per-frame work arrays of :meth:`VoxelMaps.fuse` for frames of ``pixels`` pixels, reused frame after frame."""

    def __init__(self, pixels: int) -> None:
        self.points = np.empty((pixels, 3), dtype=np.float64)
        self.targets = np.empty((pixels, 3), dtype=np.float64)
        size = 1 << max(4, (2 * pixels - 1).bit_length())  # a power of two ≥ 2 × pixels: load factor ≤ 1/2
        self.seen_keys = np.empty((size, 3), dtype=np.int64)
        self.seen_used = np.zeros(size, dtype=np.bool_)


@numba.njit(cache=True, nogil=True)
def _points_kernel(depth, xn, yn, rot, pos, push_per_m, push_min, push_max, out):
    n = 0
    for v in range(depth.shape[0]):
        for u in range(depth.shape[1]):
            z = float(depth[v, u])
            if not (z > 0.0 and z < math.inf):  # skips 0, NaN and ±inf
                continue
            z += min(push_per_m * z * z + push_min, push_max)
            x = xn[u] * z
            y = yn[v] * z
            for i in range(3):
                out[n, i] = rot[i, 0] * x + rot[i, 1] * y + rot[i, 2] * z + pos[i]
            n += 1
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def _first_visit(keys, used, ix, iy, iz):
    """Insert (ix, iy, iz) into the open-addressing set (keys, used); False if it was there already."""
    mask = used.shape[0] - 1
    slot = ((ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)) & mask  # Teschner et al.'s spatial hash
    while used[slot]:
        if keys[slot, 0] == ix and keys[slot, 1] == iy and keys[slot, 2] == iz:
            return False
        slot = (slot + 1) & mask
    used[slot] = True
    keys[slot, 0] = ix
    keys[slot, 1] = iy
    keys[slot, 2] = iz
    return True


@numba.njit(cache=True, nogil=True)
def _fuse_kernel(
    log_odds, stamp, frame, origin, res, oy, ox, points, sensor, max_range, hit, miss, lo, hi, targets, seen_keys,
    seen_used,
):  # fmt: skip
    """Discretised OctoMap insert of one point cloud into one voxel grid; returns the number of rays cast.

    Voxel coordinates count from ``origin``; the arrays hold rows oy … oy + ny − 1 and columns ox … ox + nx − 1.

    ``targets`` (≥ len(points) rows) and the set (``seen_keys``, ``seen_used``: a power-of-two size ≥ 2 ×
    len(points)) are scratch; the set is emptied here."""
    ny, nx, nz = log_odds.shape
    lo_flat = log_odds.reshape(-1)
    st_flat = stamp.reshape(-1)
    n = points.shape[0]
    # Sensor origin in voxel units.
    s0 = (sensor[0] - origin[0]) / res
    s1 = (sensor[1] - origin[1]) / res
    s2 = (sensor[2] - origin[2]) / res
    max_range_vox = max_range / res
    # Pass 1: distinct endpoint voxels; in-range ones take their hit now (and are stamped), all get a ray.
    # In-range voxels inside the box are deduplicated by their stamp, all others by the set.
    seen_used[:] = False
    n_targets = 0
    for k in range(n):
        ix = int(math.floor((points[k, 0] - origin[0]) / res))
        iy = int(math.floor((points[k, 1] - origin[1]) / res))
        iz = int(math.floor((points[k, 2] - origin[2]) / res))
        dx = ix + 0.5 - s0
        dy = iy + 0.5 - s1
        dz = iz + 0.5 - s2
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        scale = 1.0
        if dist <= max_range_vox and ox <= ix < ox + nx and oy <= iy < oy + ny and 0 <= iz < nz:
            flat = ((iy - oy) * nx + (ix - ox)) * nz + iz
            if st_flat[flat] == frame:
                continue  # this voxel already took its hit and queued its ray
            st_flat[flat] = frame
            old = lo_flat[flat]
            lo_flat[flat] = min((0 if old == -32768 else old) + hit, hi)
        else:
            if not _first_visit(seen_keys, seen_used, ix, iy, iz):
                continue  # the same ray is queued already
            if dist > max_range_vox:
                scale = max_range_vox / dist  # cut the ray: free space only, no hit
        targets[n_targets, 0] = s0 + dx * scale
        targets[n_targets, 1] = s1 + dy * scale
        targets[n_targets, 2] = s2 + dz * scale
        n_targets += 1
    # Pass 2: one miss for every voxel crossed before each ray's end voxel, unless updated this frame.
    for k in range(n_targets):
        _free_ray(
            lo_flat, st_flat, frame, ox, oy, nx, ny, nz, s0, s1, s2, targets[k, 0], targets[k, 1], targets[k, 2], miss,
            lo,
        )  # fmt: skip
    return n_targets


@numba.njit(cache=True, nogil=True, inline="always")
def _free_ray(lo_flat, st_flat, frame, ox, oy, nx, ny, nz, p0, p1, p2, e0, e1, e2, miss, lo):
    """Amanatides–Woo traversal from p to e (voxel units) inside the box [ox, ox + nx) × [oy, oy + ny) × [0, nz),
    excluding e's voxel."""
    d0 = e0 - p0
    d1 = e1 - p1
    d2 = e2 - p2
    # Where the segment t ∈ [0, 1] enters the box (slab test); nothing to do if it misses the box.
    t_lo = 0.0
    t_hi = 1.0
    for p, d, a, n in ((p0, d0, ox, nx), (p1, d1, oy, ny), (p2, d2, 0, nz)):
        if d == 0.0:
            if p < a or p >= a + n:
                return
        else:
            ta = (a - p) / d
            tb = (a + n - p) / d
            t_lo = max(t_lo, min(ta, tb))
            t_hi = min(t_hi, max(ta, tb))
    if t_lo >= t_hi:
        return
    ix = min(max(int(math.floor(p0 + d0 * t_lo)), ox), ox + nx - 1)
    iy = min(max(int(math.floor(p1 + d1 * t_lo)), oy), oy + ny - 1)
    iz = min(max(int(math.floor(p2 + d2 * t_lo)), 0), nz - 1)
    # Each step moves one index by one towards e's voxel, so the step count is their Manhattan distance;
    # a ray leaving the box stops at its face (the out_* index).
    n_steps = abs(int(math.floor(e0)) - ix) + abs(int(math.floor(e1)) - iy) + abs(int(math.floor(e2)) - iz)
    sx, out_x = (1, ox + nx) if d0 > 0 else (-1, ox - 1)
    sy, out_y = (1, oy + ny) if d1 > 0 else (-1, oy - 1)
    sz, out_z = (1, nz) if d2 > 0 else (-1, -1)
    tx = ((ix + (1 if d0 > 0 else 0)) - p0) / d0 if d0 != 0.0 else math.inf
    ty = ((iy + (1 if d1 > 0 else 0)) - p1) / d1 if d1 != 0.0 else math.inf
    tz = ((iz + (1 if d2 > 0 else 0)) - p2) / d2 if d2 != 0.0 else math.inf
    dtx = abs(1.0 / d0) if d0 != 0.0 else math.inf
    dty = abs(1.0 / d1) if d1 != 0.0 else math.inf
    dtz = abs(1.0 / d2) if d2 != 0.0 else math.inf
    flat = ((iy - oy) * nx + (ix - ox)) * nz + iz  # [y, x, z] C order
    step_x = sx * nz
    step_y = sy * nx * nz
    for _ in range(n_steps):
        # Branch-free "one miss unless updated this frame": whether a voxel was stamped is unpredictable, and a
        # mispredicted branch per voxel cost more than these unconditional stores to a cache line already loaded.
        old = lo_flat[flat]
        missed = max((0 if old == -32768 else old) + miss, lo)
        lo_flat[flat] = old if st_flat[flat] == frame else missed
        st_flat[flat] = frame
        if tx < ty and tx < tz:
            ix += sx
            if ix == out_x:
                return
            flat += step_x
            tx += dtx
        elif ty < tz:
            iy += sy
            if iy == out_y:
                return
            flat += step_y
            ty += dty
        else:
            iz += sz
            if iz == out_z:
                return
            flat += sz
            tz += dtz
