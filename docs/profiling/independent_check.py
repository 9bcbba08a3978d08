"""Check a profiling report's host figures against an independent measurement of the same calls with ``timeit``.

    python docs/profiling/independent_check.py docs/profiling/report.json

``edge-explorer profile`` times the stages inside the daemon's running loop (its StageTimings) and each model with
its own timer; this script calls the same functions in a plain ``timeit`` loop instead — fuse on depth frames
rendered at 30 seeded poses in building A, project both maps, the predictor's whole stage (window, network,
unshift) on the projected map, and every model on every backend the report measured — and prints both medians and
their difference. ``timeit`` figures are the median over 5 repeats of the mean of ``number`` calls.
"""

from __future__ import annotations

import itertools
import json
import sys
import timeit
from pathlib import Path

import numpy as np

from edge_explorer.backends.chain import load_model
from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.profiling.models import feed_for
from edge_explorer.runtime.daemon import band_z_range_m
from edge_explorer.sim.camera import CameraPose, DepthCamera
from edge_explorer.world.catalog import load_building

REPEATS = 5


def per_call_ms(call, number: int) -> float:
    call()  # warm-up (JIT, caches)
    return 1e3 * float(np.median(timeit.repeat(call, number=number, repeat=REPEATS))) / number


def main(report_path: str) -> None:
    doc = json.loads(Path(report_path).read_text())
    stages = doc["loop"]["stages"]
    raster = load_building(doc["loop"]["plan"])
    camera = DepthCamera(raster)
    rng = np.random.default_rng(0)
    free = np.argwhere(raster.interior & ~raster.occupied)
    frames = []
    x0, y0 = raster.grid.origin_xy
    res = raster.grid.resolution_m
    for i, j in free[rng.choice(len(free), 30, replace=False)]:
        pose = CameraPose(x0 + (j + 0.5) * res, y0 + (i + 0.5) * res, 1.7, float(rng.uniform(-np.pi, np.pi)))
        frames.append((camera.render(pose, rng), pose.position_m, pose.rotation_map_from_optical()))
    band = HeightBand()
    maps = VoxelMaps(VoxelRegion.covering(raster.grid, *band_z_range_m(band)))  # the daemon's region
    cycle, stamps = itertools.cycle(frames), itertools.count(1)

    def fuse() -> None:
        depth, position, rotation = next(cycle)
        maps.fuse(depth, camera.config.intrinsics, position, rotation, 0.1 * next(stamps))

    rows = [("fuse (loop stage)", stages["fuse"]["p50_ms"], per_call_ms(fuse, 30))]
    rows.append(
        (
            "project (loop stage)",
            stages["project"]["p50_ms"],
            per_call_ms(lambda: (project(maps.high, band), project(maps.low, band)), 10),
        )
    )
    models_dir = Path(doc["models"][0]["card"]).parents[1]
    engines = doc["loop"]["engines"]
    if "predictor" in engines and "predictor" in stages:
        e = engines["predictor"]
        predictor = PredictorRuntime(load_model(models_dir / "predictor", (e["backend"],), e["precision"]))
        low, low_grid = project(maps.low, band)
        cell = tuple(int(v) for v in np.argwhere(low != 0).mean(axis=0))
        rows.append(
            (
                "predictor (loop stage)",
                stages["predictor"]["p50_ms"],
                per_call_ms(lambda: predictor.predict(low, cell), 10),
            )
        )
    for model in doc["models"]:
        for run in model["runs"]:
            if run["latency_ms"] is None:
                continue
            loaded = load_model(Path(model["card"]), (run["backend"],), run["precision"])
            feed = feed_for(loaded.backend.inputs)
            label = f"{model['name']} {run['precision']} on {run['backend']} (model run)"
            rows.append(
                (label, run["latency_ms"]["p50_ms"], per_call_ms(lambda loaded=loaded, feed=feed: loaded.run(feed), 20))
            )
    print("| call | report p50 (ms) | timeit (ms) | difference |\n| --- | ---: | ---: | ---: |")
    for label, report_ms, timeit_ms in rows:
        print(f"| {label} | {report_ms:.2f} | {timeit_ms:.2f} | {100 * (report_ms - timeit_ms) / timeit_ms:+.1f} % |")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/profiling/report.json")
