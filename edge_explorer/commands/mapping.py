"""``edge-explorer map bench``: depth-frame mapping speed and accuracy on a bundled building (optionally vs OctoMap).

The bench flies a fixed, deterministic trajectory through the building: goals are spread over the configuration
space by farthest-point sampling on geodesic distance (every free spot within ``GOAL_SPACING_M`` of a goal; at
least two goals), visited in greedy nearest-first order along shortest grid paths, at flight height with the
camera yawing ±60° about the direction of travel. ``--frames N`` samples N poses evenly along that whole tour,
so any N covers the building. Each frame is rendered (noise on by default), fused into both voxel maps and
timed; the maps are then projected and compared with the plan's ground truth (observed interior cells only).
``--vs-octomap`` inserts the very same point clouds into two OctoMap trees (0.05 m and 0.20 m; same sensor
origin, max range and hit/miss/clamp parameters; OctoMap's ``discretize=True`` insert, the algorithm ours
reproduces, with its default insert timed as well) on the same single core, and compares the projected maps cell
by cell.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge_explorer.cli_support import positive_int

if TYPE_CHECKING:
    import numpy as np

    from edge_explorer.mapping.voxels import FusionConfig
    from edge_explorer.vehicle.camera import CameraPose
    from edge_explorer.world.raster import PlanRaster

DESCRIPTION = "Depth-frame mapping: benchmark voxel fusion and projection (optionally against OctoMap)."
FLIGHT_HEIGHT_M = 1.7
FRAME_RATE_HZ = 30.0
PATH_CLEARANCE_M = 0.35  # the tour keeps this far from obstacles (doors are ≥ 0.80 m, so it still fits them)
GOAL_SPACING_M = 3.0
SWEEP_RAD = math.radians(60.0)
SWEEP_PERIOD_M = 4.0
OCTOMAP_PACKAGE = "octomap-python"


def register(sub: argparse._SubParsersAction) -> None:
    mp = sub.add_parser("map", help="depth-frame mapping: bench", description=DESCRIPTION)
    msub = mp.add_subparsers(dest="map_command", metavar="ACTION", required=True)
    bench = msub.add_parser("bench", help="render a fixed trajectory, fuse every frame, report speed and accuracy")
    bench.add_argument("--frames", type=positive_int, default=300, help="frames along the tour (default 300)")
    bench.add_argument("--plan", default="A", help="A-D, a plan .json or a map_server .yaml (default A)")
    bench.add_argument("--json", type=Path, help="write the figures here")
    bench.add_argument("--png", type=Path, help="draw a depth frame and the projected maps beside the plan")
    bench.add_argument(
        "--vs-octomap", action="store_true", help=f"also insert the frames into OctoMap ({OCTOMAP_PACKAGE})"
    )
    bench.add_argument("--no-noise", action="store_true", help="render exact depth (default: D435-like noise)")
    bench.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    bench.set_defaults(func=_bench)


def bench_trajectory(raster: PlanRaster, n_frames: int) -> list[CameraPose]:
    """The bench's fixed tour through ``raster`` (see module docstring), sampled at ``n_frames`` poses."""
    import numpy as np
    from scipy import ndimage
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.vehicle.camera import CameraPose
    from edge_explorer.world.raster import clearance_m, configuration_space

    free = configuration_space(raster, PATH_CLEARANCE_M)
    labels, count = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        raise EdgeExplorerError(f"{raster.name}: no free space {PATH_CLEARANCE_M} m away from obstacles to fly in")
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    free = labels == sizes.argmax()
    cells = np.argwhere(free)
    node = np.full(free.shape, -1, dtype=np.int64)
    node[free] = np.arange(len(cells))
    # 8-connected grid graph, edge lengths in metres.
    src, dst, length = [], [], []
    res = raster.grid.resolution_m
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = cells[:, 0] + dr, cells[:, 1] + dc
        ok = (r2 >= 0) & (r2 < free.shape[0]) & (c2 >= 0) & (c2 < free.shape[1])
        ok[ok] &= free[r2[ok], c2[ok]]
        src.append(node[cells[ok, 0], cells[ok, 1]])
        dst.append(node[r2[ok], c2[ok]])
        length.append(np.full(ok.sum(), res * math.hypot(dr, dc)))
    graph = coo_matrix((np.concatenate(length), (np.concatenate(src), np.concatenate(dst))), shape=(len(cells),) * 2)
    graph = graph.tocsr()

    clearance = clearance_m(raster)[free]
    goals = [int(np.argmax(clearance))]  # start where the vehicle is farthest from everything
    dist, pred = dijkstra(graph, directed=False, indices=goals[0], return_predecessors=True)
    dists, preds = [dist], [pred]
    nearest = dist.copy()
    while nearest.max() > GOAL_SPACING_M or (len(goals) < 2 and nearest.max() > 0):
        goals.append(int(np.argmax(nearest)))
        dist, pred = dijkstra(graph, directed=False, indices=goals[-1], return_predecessors=True)
        dists.append(dist)
        preds.append(pred)
        nearest = np.minimum(nearest, dist)

    order, todo = [0], set(range(1, len(goals)))
    while todo:
        here = order[-1]
        nxt = min(todo, key=lambda k: (dists[here][goals[k]], k))
        order.append(nxt)
        todo.remove(nxt)
    path = [goals[0]]
    for a, b in zip(order[:-1], order[1:], strict=True):
        leg, n = [], goals[b]
        while n != goals[a]:
            leg.append(n)
            n = preds[a][n]
        path.extend(reversed(leg))

    xy = np.stack(raster.grid.center_of(cells[path, 0], cells[path, 1]), axis=1)
    if len(xy) > 1:  # smooth the grid staircase (a 0.25 m window stays well inside the clearance)
        k = 5
        padded = np.concatenate([np.repeat(xy[:1], k, 0), xy, np.repeat(xy[-1:], k, 0)])
        kernel = np.ones(2 * k + 1) / (2 * k + 1)
        xy = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(2)], axis=1)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    s = np.linspace(0.0, arc[-1], n_frames)
    ahead = 0.25
    dx = np.interp(s + ahead, arc, xy[:, 0]) - np.interp(s - ahead, arc, xy[:, 0])
    dy = np.interp(s + ahead, arc, xy[:, 1]) - np.interp(s - ahead, arc, xy[:, 1])
    heading = np.arctan2(dy, dx) if arc[-1] > 0 else np.zeros(n_frames)
    yaw = heading + SWEEP_RAD * np.sin(2 * math.pi * s / SWEEP_PERIOD_M)
    x, y = np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])
    return [CameraPose(float(x[i]), float(y[i]), FLIGHT_HEIGHT_M, float(yaw[i])) for i in range(n_frames)]


def _stats_ms(seconds: list[float]) -> dict[str, float]:
    import numpy as np

    ms = np.asarray(seconds) * 1e3
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "mean": float(ms.mean())}


def _truth_agreement(codes: np.ndarray, raster: PlanRaster) -> dict[str, float | int]:
    """Fraction of observed interior cells whose projected state equals the ground truth, and where the rest are.

    ``wrong_beside_obstacle``: free cells next to an obstacle (4-neighbour) mapped occupied, i.e. obstacles grown
    by a cell; ``wrong_free``: obstacle cells mapped free; ``wrong_other``: the remaining wrong cells.
    """
    from scipy import ndimage

    from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN

    truth = raster.truth_codes()
    observed = raster.interior & (codes != UNKNOWN)
    wrong = observed & (codes != truth)
    beside = ndimage.binary_dilation(truth == OCCUPIED) & (truth == FREE)
    n = int(observed.sum())
    n_beside = int((wrong & beside & (codes == OCCUPIED)).sum())
    n_free = int((wrong & (truth == OCCUPIED) & (codes == FREE)).sum())
    return {
        "observed_interior_cells": n,
        "interior_cells": int(raster.interior.sum()),
        "correct_fraction": float(1.0 - wrong.sum() / n) if n else float("nan"),
        "wrong_beside_obstacle": n_beside,
        "wrong_free": n_free,
        "wrong_other": int(wrong.sum()) - n_beside - n_free,
    }


def _pair_agreement(a: np.ndarray, b: np.ndarray) -> dict[str, float | int]:
    from edge_explorer.world.grid import UNKNOWN

    both = (a != UNKNOWN) & (b != UNKNOWN)
    n = int(both.sum())
    return {
        "cells_both_know": n,
        "agree_fraction": float((a[both] == b[both]).sum() / n) if n else float("nan"),
        "known_only_ours": int(((a != UNKNOWN) & (b == UNKNOWN)).sum()),
        "known_only_octomap": int(((a == UNKNOWN) & (b != UNKNOWN)).sum()),
    }


class _OctoMapRunner:
    """Two OctoMap trees fed the same clouds; points are shifted by the voxel region's origin so that OctoMap's
    voxel boundaries (multiples of its resolution from 0) coincide with ours."""

    def __init__(self, shift_m: np.ndarray, resolutions_m: tuple[float, float], config: Any) -> None:
        from edge_explorer.errors import EdgeExplorerError

        try:
            import octomap
        except ImportError:
            raise EdgeExplorerError(
                f"--vs-octomap needs the {OCTOMAP_PACKAGE} package: pip install -e '.[dev]'"
            ) from None
        self.shift_m = shift_m
        self.max_range_m = config.max_range_m
        self.trees = {}
        for mode in ("discrete", "default"):
            for res in resolutions_m:
                tree = octomap.OcTree(res)
                tree.setProbHit(config.prob_hit)
                tree.setProbMiss(config.prob_miss)
                tree.setClampingThresMin(config.clamp_min)
                tree.setClampingThresMax(config.clamp_max)
                tree.setOccupancyThres(config.occupancy_threshold)
                self.trees[(mode, res)] = tree

    def insert(self, points_m: np.ndarray, origin_m: np.ndarray, mode: str) -> float:
        """Insert one cloud into both trees of ``mode``; returns the seconds the two inserts took."""
        import numpy as np

        local = np.ascontiguousarray(points_m - self.shift_m)
        origin = np.ascontiguousarray(origin_m - self.shift_m)
        start = time.perf_counter()
        for (m, _), tree in self.trees.items():
            if m == mode:
                tree.insertPointCloud(local, origin, maxrange=self.max_range_m, discretize=(mode == "discrete"))
        return time.perf_counter() - start

    def project(self, mode: str, like: Any, band: Any) -> np.ndarray:
        """The tree's map sampled at the voxel centres of ``like`` (our VoxelGrid), projected by our column rule."""
        import numpy as np

        from edge_explorer.mapping.projection import project_states
        from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

        r = like.resolution_m
        z = like.layer_centers_m()
        layers = band.layers(z)
        rows, cols = like.shape[:2]
        gy, gx, gz = np.meshgrid(
            (np.arange(rows) + 0.5) * r, (np.arange(cols) + 0.5) * r, (layers + 0.5) * r, indexing="ij"
        )
        labels = self.trees[(mode, r)].getLabels(np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1))
        states = np.full(labels.shape, UNKNOWN, dtype=CELL_DTYPE)  # getLabels: -1 unknown, 0 free, 1 occupied
        states[labels == 0] = FREE
        states[labels == 1] = OCCUPIED
        return project_states(states.reshape(rows, cols, len(layers)), z[layers] - r / 2, band)


def run_bench(
    raster: PlanRaster,
    n_frames: int,
    noise: bool = True,
    seed: int = 0,
    vs_octomap: bool = False,
    config: FusionConfig | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run the bench; returns (the JSON report, pictures' data: a depth frame, projected maps, poses)."""
    import numpy as np
    from tqdm import tqdm

    from edge_explorer.mapping.projection import HeightBand, align_to_grid, project
    from edge_explorer.mapping.voxels import FusionConfig, VoxelMaps, VoxelRegion, depth_to_points
    from edge_explorer.sim.camera import DepthCamera
    from edge_explorer.vehicle.camera import CameraConfig
    from edge_explorer.world.grid import LOW_RES_M

    camera_config = CameraConfig() if noise else CameraConfig(noise=None)
    camera = DepthCamera(raster, camera_config)
    intrinsics = camera_config.intrinsics
    region = VoxelRegion.covering(raster.grid, z_max_m=raster.ceiling_height_m + 0.3)
    config = config or FusionConfig()
    band = HeightBand()
    maps = VoxelMaps(region, config)
    resolutions = (maps.high.resolution_m, maps.low.resolution_m)
    octo = _OctoMapRunner(np.asarray(region.origin_xyz_m), resolutions, config) if vs_octomap else None
    poses = bench_trajectory(raster, n_frames)
    rng = np.random.default_rng(seed)

    # Warm-up (numba compilation / cache load) on a throwaway map, so frame 0 is timed like the rest.
    warm = camera.render(poses[0], rng=None)
    VoxelMaps(region, config).fuse(warm, intrinsics, poses[0].position_m, poses[0].rotation_map_from_optical(), 0.0)

    render_s, fuse_s, octo_s, octo_default_s, n_points = [], [], [], [], 0
    keep, keep_spread = 0, -1.0  # the picture shows the frame with the widest spread of depths
    kept_depth = warm
    for i, pose in enumerate(tqdm(poses, desc=f"map bench {raster.name}", unit="frame", leave=False)):
        t0 = time.perf_counter()
        depth = camera.render(pose, rng if noise else None)
        t1 = time.perf_counter()
        position, rotation = pose.position_m, pose.rotation_map_from_optical()
        stats = maps.fuse(depth, intrinsics, position, rotation, i / FRAME_RATE_HZ)
        t2 = time.perf_counter()
        render_s.append(t1 - t0)
        fuse_s.append(t2 - t1)
        n_points += stats.points
        spread = float(np.std(depth[depth > 0])) if stats.points else 0.0
        if spread > keep_spread:
            keep, keep_spread, kept_depth = i, spread, depth
        if octo is not None:
            points = depth_to_points(depth, intrinsics, position, rotation, config)
            octo_s.append(octo.insert(points, position, "discrete"))
            octo_default_s.append(octo.insert(points, position, "default"))

    low_raster = raster.coarsened(LOW_RES_M)
    ours, truth = {}, {}
    for vox, target in ((maps.high, raster), (maps.low, low_raster)):
        codes, grid = project(vox, band)
        ours[vox.resolution_m] = align_to_grid(codes, grid, target.grid)
        truth[f"{vox.resolution_m:.2f}"] = _truth_agreement(ours[vox.resolution_m], target)

    report: dict[str, Any] = {
        "plan": raster.name,
        "frames": n_frames,
        "image_px": [intrinsics.width_px, intrinsics.height_px],
        "noise": None if camera_config.noise is None else vars(camera_config.noise),
        "seed": seed,
        "fusion": vars(config),
        "resolutions_m": list(resolutions),
        "height_band_m": [band.min_z_m, band.max_z_m],
        "region": {"origin_xyz_m": list(region.origin_xyz_m), "size_xyz_m": list(region.size_xyz_m)},
        "render_ms": _stats_ms(render_s),
        "fuse_ms": _stats_ms(fuse_s),
        "points_per_frame": n_points / n_frames,
        "points_per_s": n_points / sum(fuse_s),
        "truth_agreement": truth,
        "single_thread": True,
    }
    pictures: dict[str, Any] = {"depth": kept_depth, "pose": poses[keep], "poses": poses, "ours": ours}
    if octo is not None:
        agreement, theirs = {}, {}
        for vox, target in ((maps.high, raster), (maps.low, low_raster)):
            codes = align_to_grid(octo.project("discrete", vox, band), vox.grid, target.grid)
            theirs[vox.resolution_m] = codes
            agreement[f"{vox.resolution_m:.2f}"] = {
                **_pair_agreement(ours[vox.resolution_m], codes),
                "octomap_truth": _truth_agreement(codes, target),
            }
        octo_ms = _stats_ms(octo_s)
        report["octomap"] = {
            "package": f"{OCTOMAP_PACKAGE}=={_version(OCTOMAP_PACKAGE)}",
            "insert": "insertPointCloud(discretize=True), both trees per frame",
            "ms": octo_ms,
            "speed_ratio_median": octo_ms["median"] / report["fuse_ms"]["median"],
            "speed_ratio_mean": octo_ms["mean"] / report["fuse_ms"]["mean"],
            "default_insert_ms": _stats_ms(octo_default_s),
            "default_insert_speed_ratio_median": _stats_ms(octo_default_s)["median"] / report["fuse_ms"]["median"],
            "agreement": agreement,
        }
        pictures["octomap"] = theirs
    return report, pictures


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


def _print_table(report: dict[str, Any]) -> None:
    rows = [
        ("render (212×120)", f"{report['render_ms']['median']:.2f}", f"{report['render_ms']['p95']:.2f}", ""),
        (
            "fuse 0.05+0.20 m",
            f"{report['fuse_ms']['median']:.2f}",
            f"{report['fuse_ms']['p95']:.2f}",
            f"{report['points_per_s'] / 1e6:.2f} Mpt/s",
        ),
    ]
    octo = report.get("octomap")
    if octo:
        rows.append(
            (
                "OctoMap discretize",
                f"{octo['ms']['median']:.1f}",
                f"{octo['ms']['p95']:.1f}",
                f"×{octo['speed_ratio_median']:.1f} slower",
            )
        )
        rows.append(
            (
                "OctoMap default",
                f"{octo['default_insert_ms']['median']:.1f}",
                f"{octo['default_insert_ms']['p95']:.1f}",
                f"×{octo['default_insert_speed_ratio_median']:.1f} slower",
            )
        )
    print(f"map bench: plan {report['plan']}, {report['frames']} frames, noise {'on' if report['noise'] else 'off'}")
    print(f"{'stage':<20}{'median ms':>11}{'p95 ms':>9}  note")
    for name, med, p95, note in rows:
        print(f"{name:<20}{med:>11}{p95:>9}  {note}")
    for res, t in report["truth_agreement"].items():
        line = f"{res} m map vs truth: {100 * t['correct_fraction']:.2f} % of {t['observed_interior_cells']} observed"
        line += f" interior cells correct ({100 * t['observed_interior_cells'] / t['interior_cells']:.0f} % observed)"
        if octo:
            a = octo["agreement"][res]
            line += f"; vs OctoMap {100 * a['agree_fraction']:.2f} % of {a['cells_both_know']} cells both know"
        print(line)


def save_bench_png(raster: PlanRaster, pictures: dict[str, Any], path: Path) -> None:
    """Depth frame | plan with the tour | projected 0.05 m map | projected 0.20 m map (wrong cells in red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from edge_explorer.world.grid import FREE, LOW_RES_M, OCCUPIED
    from edge_explorer.world.render import plan_rgb

    def map_rgb(codes: np.ndarray, truth: PlanRaster) -> np.ndarray:
        img = np.full(codes.shape + (3,), 170, dtype=np.uint8)
        img[codes == FREE] = 255
        img[codes == OCCUPIED] = 30
        wrong = truth.interior & (codes != 0) & (codes != truth.truth_codes())
        img[wrong] = (220, 30, 30)
        return img[::-1]

    g = raster.grid
    extent = (g.origin_xy[0], g.origin_xy[0] + g.size_xy_m[0], g.origin_xy[1], g.origin_xy[1] + g.size_xy_m[1])
    fig, axes = plt.subplots(2, 2, figsize=(13, 7.5), dpi=110)
    depth = np.where(pictures["depth"] > 0, pictures["depth"], np.nan)
    im = axes[0, 0].imshow(depth, cmap="viridis")
    pose = pictures["pose"]
    axes[0, 0].set_title(f"depth frame at ({pose.x_m:.1f}, {pose.y_m:.1f}) m, yaw {math.degrees(pose.yaw_rad):.0f}°")
    fig.colorbar(im, ax=axes[0, 0], label="z-depth [m] (blank = no return)")
    axes[0, 1].imshow(plan_rgb(raster), extent=extent, interpolation="nearest")
    xs = [p.x_m for p in pictures["poses"]]
    ys = [p.y_m for p in pictures["poses"]]
    axes[0, 1].plot(xs, ys, "-", color="tab:blue", lw=0.8)
    axes[0, 1].plot([pose.x_m], [pose.y_m], "o", color="tab:red")
    axes[0, 1].set_title(f"plan {raster.name} and the bench tour")
    low = raster.coarsened(LOW_RES_M)
    for ax, res, truth in ((axes[1, 0], raster.grid.resolution_m, raster), (axes[1, 1], LOW_RES_M, low)):
        ax.imshow(map_rgb(pictures["ours"][res], truth), extent=extent, interpolation="nearest")
        ax.set_title(f"projected {res:.2f} m map (band 1.5–2.5 m; red = differs from plan)")
    for ax in axes.ravel()[1:]:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def _bench(args: argparse.Namespace) -> int:
    from edge_explorer.cli_support import write_json
    from edge_explorer.world.catalog import load_building

    raster = load_building(args.plan)
    report, pictures = run_bench(
        raster, args.frames, noise=not args.no_noise, seed=args.seed, vs_octomap=args.vs_octomap
    )
    _print_table(report)
    write_json(args.json, report)
    if args.png:
        save_bench_png(raster, pictures, args.png)
        print(f"wrote {args.png}")
    return 0
