"""Check a profiling report's host figures against an independent measurement of the same calls on the same inputs.

    edge-explorer profile --profile host --record runs/profile-recording --out docs/profiling
    python scripts/independent_check.py docs/profiling/report.json [--recording runs/profile-recording]

``edge-explorer profile`` times the stages inside the daemon's running loop (its StageTimings) and each model with
its own timer. With ``--record`` the profiler also keeps every frame the loop fused, with the pose it was fused
with, and the loop's own duration of every fuse / project / predictor / policy call (``loop_timings.json``). This
script replays that recording outside the loop — the same frames and poses fused in the same order into fresh maps,
the same projections (both maps and the flown-footprint mask, as the daemon's ``project`` stage), the same
predictor calls after the same frames, and the policy on the observation built from them (thresholding and the ego
transform untimed between the two, as in the loop; the previous action is not recorded, so the observation's
one-hot says "forward": the int8 graph's work does not depend on the values) — times each call on its own with
``timeit`` (one call per sample, the median compared with the loop's median over the same measured window), and
runs every model the report measured on its backend
the same way. Three replays: back to back (nothing else between the calls); with the simulated camera rendering
each frame's pose before that frame is fused, as the loop does in the same thread; and paced as recorded, the
renderer between frames: the thread sleeps until each frame's recorded time, as the loop's thread waits for the
camera. The paced replay is the closest to the loop's conditions: on this host a thread that has idled runs the
same calls up to twice as slowly for the next tens of milliseconds (measured in session 38; git history), and
the loop's thread idles most of every frame period, while a back-to-back replay never does. The fuse calls
are also compared by thread CPU time (the loop meters it when recording), and the loop's calls that the scheduler
never preempted are compared on their own: they separate time spent computing from time spent waiting for a core.
For each replayed stage the notes give the share of calls slower than 1.4 × the back-to-back median, with medians
and means, for the loop and each replay: a call is either fast (as back to back) or slow (as after idling), and
the share of slow ones moves a median by up to the whole gap between the two.
"""

from __future__ import annotations

import argparse
import json
import time
import timeit
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from edge_explorer.backends.chain import load_model
from edge_explorer.mapping.ego import observation_from_maps
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.profiling.loop import RECORDED_TIMINGS, REPLAYED_STAGES
from edge_explorer.profiling.models import feed_for
from edge_explorer.runtime.daemon import band_z_range_m
from edge_explorer.runtime.depth_sources import ReplayDepthSource
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.vehicle.dynamics import Action
from edge_explorer.world.catalog import load_building
from edge_explorer.world.grid import FREE, UNKNOWN

MODEL_SAMPLES = 100
SLOW = 1.4  # a call this many times the back-to-back median counts as slow


def timed_ms(call: Callable[[], object]) -> float:
    """One call's duration in milliseconds, by ``timeit`` (its default timer, ``time.perf_counter``)."""
    return 1e3 * timeit.timeit(call, number=1)


def replay(
    recording: Path,
    timings: dict,
    predictor: PredictorRuntime | None,
    policy: PolicyRuntime | None,
    render: bool,
    paced: bool = False,
) -> dict[str, np.ndarray]:
    """Fuse the recording's frames in order; project (predict, act) where the loop decided. Per-call ms per stage."""
    raster = load_building(timings["plan"])
    band = HeightBand(**timings["band"])
    maps = VoxelMaps(VoxelRegion.covering(raster.grid, *band_z_range_m(band)))  # the daemon's maps
    flown = np.zeros(maps.high.grid.shape, dtype=np.uint8)
    radius_cells = int(timings["footprint_clear_m"] / maps.high.resolution_m)
    camera = DepthCamera(raster) if render else None
    rng = np.random.default_rng(0)
    decisions_after = {}
    for d, frames in enumerate(timings["decision_frames"]):
        decisions_after.setdefault(frames, []).append(d)
    out: dict[str, list[float]] = {"fuse": [], "fuse_cpu": [], "project": [], "predictor": [], "policy": []}
    source = ReplayDepthSource(recording, realtime=paced)
    while not source.finished:
        frame = source.next_frame()
        if frame is None:  # a paced replay waited longer than the source's timeout: ask again
            continue
        p = frame.pose
        pose = CameraPose(p.x_m, p.y_m, p.z_m, p.yaw_rad, p.pitch_rad, p.roll_rad)
        position, rotation = pose.position_m, pose.rotation_map_from_optical()
        if camera is not None:
            camera.render(pose, rng)
        cpu0 = time.thread_time()
        out["fuse"].append(
            timed_ms(lambda: maps.fuse(frame.depth_m, frame.intrinsics, position, rotation, frame.stamp_s))  # noqa: B023
        )
        out["fuse_cpu"].append(1e3 * (time.thread_time() - cpu0))
        if radius_cells > 0 and p.z_m >= band.min_z_m:  # the daemon's flown footprint
            row, col = maps.high.grid.cell_of(p.x_m, p.y_m)
            cv2.circle(flown, (int(col), int(row)), radius_cells, 1, thickness=-1)
        for _ in decisions_after.get(maps.frames_fused, ()):
            projected: list[ObservedMaps] = []

            def project_stage() -> None:
                high, high_grid = project(maps.high, band)
                high[(flown != 0) & (high == UNKNOWN)] = FREE
                low, low_grid = project(maps.low, band)
                projected.append(ObservedMaps(high_grid, low_grid, high, low))  # noqa: B023

            out["project"].append(timed_ms(project_stage))
            if predictor is None:
                continue
            observed = projected[0]
            low_cell = tuple(int(v) for v in observed.low_grid.cell_of(p.x_m, p.y_m))
            probabilities: list[np.ndarray] = []
            out["predictor"].append(
                timed_ms(lambda: probabilities.append(predictor.predict(observed.low, low_cell)))  # noqa: B023
            )
            if policy is None:
                continue
            thres = thresholded_map(probabilities[0], observed.low, observed.observed_area_m2(), ThresholdConfig())
            high_cell = tuple(int(v) for v in observed.high_grid.cell_of(p.x_m, p.y_m))
            observation = observation_from_maps(
                observed.high,
                thres,
                observed.high_grid.resolution_m,
                observed.low_grid.resolution_m,
                high_cell,
                low_cell,
                p.yaw_rad,
                Action.FORWARD,
            )
            out["policy"].append(timed_ms(lambda: policy.act(observation)))  # noqa: B023
    return {stage: np.asarray(ms) for stage, ms in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, nargs="?", default=Path("docs/profiling/report.json"))
    parser.add_argument("--recording", type=Path, help="the profile's --record folder (default: the report's)")
    args = parser.parse_args()
    doc = json.loads(args.report.read_text())
    recording = args.recording or (Path(doc["loop"]["recording"]) if doc["loop"].get("recording") else None)
    if recording is None or not (recording / RECORDED_TIMINGS).is_file():
        raise SystemExit(f"no recording with {RECORDED_TIMINGS}: run edge-explorer profile with --record DIR")
    timings = json.loads((recording / RECORDED_TIMINGS).read_text())
    loop_ms = {stage: np.asarray(ms) for stage, ms in timings["samples_ms"].items()}
    start = timings["window_start"]
    stages = doc["loop"]["stages"]
    models_dir = Path(doc["models"][0]["card"]).parents[1]
    engines = doc["loop"]["engines"]
    predictor = policy = None
    if "predictor" in engines:
        engine = engines["predictor"]
        predictor = PredictorRuntime(load_model(models_dir / "predictor", (engine["backend"],), engine["precision"]))
    if "policy" in engines:
        engine = engines["policy"]
        policy = PolicyRuntime(load_model(models_dir / "policy", (engine["backend"],), engine["precision"]))

    runs = {"back to back": replay(recording, timings, predictor, policy, render=False)}
    runs["renderer between frames"] = replay(recording, timings, predictor, policy, render=True)
    runs["paced as recorded, renderer between frames"] = replay(
        recording, timings, predictor, policy, render=True, paced=True
    )
    if timings.get("fuse_cpu_from") is not None:  # the loop's fuse thread CPU, on the fuse samples' indices
        cpu = np.full(len(loop_ms["fuse"]), np.nan)
        cpu[timings["fuse_cpu_from"] : timings["fuse_cpu_from"] + len(timings["fuse_cpu_ms"])] = timings["fuse_cpu_ms"]
        loop_ms["fuse_cpu"] = cpu
        start["fuse_cpu"] = start["fuse"]
    rows = []
    for stage in ("fuse", "fuse_cpu", "project", "predictor", "policy"):
        if stage not in loop_ms or not len(loop_ms[stage]) or not len(runs["back to back"][stage]):
            continue
        window = loop_ms[stage][start[stage] :]
        loop_p50 = stages[stage]["p50_ms"] if stage in stages else float(np.nanmedian(window))
        label = "fuse thread CPU (metered in the loop)" if stage == "fuse_cpu" else f"{stage} (loop stage)"
        for name, replayed in runs.items():
            same = replayed[stage][start[stage] : start[stage] + len(window)]
            paired = np.nanmedian(window[: len(same)] / same)
            rows.append((f"{label}, replay {name}", loop_p50, float(np.median(same)), paired))
    notes = []
    if timings.get("fuse_preempted"):  # the fuse calls the scheduler never interrupted, against the same replayed
        first = timings["fuse_cpu_from"]
        preempted = np.asarray(timings["fuse_preempted"])[start["fuse"] - first :]
        calm = np.flatnonzero(preempted == 0)
        window = loop_ms["fuse"][start["fuse"] :]
        same = runs["back to back"]["fuse"][start["fuse"] : start["fuse"] + len(window)]
        calm = calm[calm < len(same)]
        notes.append(
            f"fuse calls in the loop's window preempted by the scheduler (≥ 1 involuntary context switch): "
            f"{100 * (preempted > 0).mean():.0f} %, {preempted.mean():.2f} switches a call"
        )
        if len(calm):
            loop_calm, replay_calm = window[calm], same[calm]
            paired = np.median(loop_calm / replay_calm)
            notes.append(
                f"the {len(calm)} calls never preempted: loop p50 {np.median(loop_calm):.2f} ms, the same frames "
                f"replayed back to back {np.median(replay_calm):.2f} ms (paired {paired:.2f})"
            )
    for model in doc["models"]:
        for run in model["runs"]:
            if run["latency_ms"] is None:
                continue
            loaded = load_model(Path(model["card"]), (run["backend"],), run["precision"])
            feed = feed_for(loaded.backend.inputs)
            for _ in range(5):
                loaded.run(feed)  # warm-up, as the profiler's
            ms = [timed_ms(lambda loaded=loaded, feed=feed: loaded.run(feed)) for _ in range(MODEL_SAMPLES)]
            label = f"{model['name']} {run['precision']} on {run['backend']} (model run)"
            rows.append((label, run["latency_ms"]["p50_ms"], float(np.median(ms)), None))
    print("| call | loop p50 (ms) | timeit p50 (ms) | difference | paired loop / replay (median) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for label, report_ms, timeit_ms, paired in rows:
        ratio = "" if paired is None else f"{paired:.2f}"
        difference = 100 * (report_ms - timeit_ms) / timeit_ms
        print(f"| {label} | {report_ms:.2f} | {timeit_ms:.2f} | {difference:+.1f} % | {ratio} |")
    for stage in REPLAYED_STAGES:
        if stage not in loop_ms or not len(loop_ms[stage]) or not len(runs["back to back"][stage]):
            continue
        window = loop_ms[stage][start[stage] :]
        fast = float(np.median(runs["back to back"][stage][start[stage] : start[stage] + len(window)]))
        shares = []
        replays = ((f"replay {name}", r[stage][start[stage] : start[stage] + len(window)]) for name, r in runs.items())
        for name, same in (("loop", window), *replays):
            shares.append(
                f"{name} {100 * (same > SLOW * fast).mean():.0f} % (median {np.median(same):.2f}, mean "
                f"{same.mean():.2f} ms)"
            )
        notes.append(f"{stage} calls slower than {SLOW} × the back-to-back median ({fast:.2f} ms): {'; '.join(shares)}")
    for note in notes:
        print(f"\n{note}")


if __name__ == "__main__":
    main()
