"""Where the loop's policy and project time goes: the same calls under the conditions a decision runs them in.

    python docs/profiling/stage_conditions.py [--models models] [--repeats 200]

The loop's policy stage (``PolicyRuntime.act``) and project stage (:func:`~edge_explorer.mapping.projection.project`
of the 0.05 m map) take longer than the same calls back to back. This times each call repeated after each of:
nothing (back to back); the int8 predictor (what runs before the policy in a decision); a 32 MB sweep (caches
evicted); 50 ms of sleep (the loop's thread idles between depth frames); 50 ms of sleep then 20 ms of computing
(about what the loop computes between a frame's arrival and the policy). Thread CPU time is printed beside wall
time: when they agree the call was computing, not waiting for a core. Then the policy graph node by node
(onnxruntime's profiler: the share of the convolutions and dense layers against the input-encoding, quantize and
layout nodes, and the bytes of activations the nodes read and write per run), and the onnxruntime session settings
that could matter, each on the same inputs after the predictor (their actions checked identical). Observations come
from plan A's true map with a third of its cells unknown; the projected map is plan A fused from a spin at three
poses (the daemon's band-limited box).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnxruntime as ort

from edge_explorer.backends.chain import load_model
from edge_explorer.mapping.ego import observation_from_maps
from edge_explorer.mapping.projection import HeightBand, project
from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.runtime.daemon import band_z_range_m
from edge_explorer.sim.camera import DepthCamera
from edge_explorer.vehicle.camera import CameraPose
from edge_explorer.world.catalog import load_building
from edge_explorer.world.grid import UNKNOWN

SWEEP_32MB = np.ones(8_000_000, dtype=np.float32)
COMPUTE_LAYERS = ("QLinearConv", "QGemm")  # the convolutions and the dense layers; the rest encodes and reshapes


def spin_wait(seconds: float) -> None:
    """Compute (no memory traffic) for ``seconds``."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def observations(count: int) -> tuple[list[dict[str, np.ndarray]], np.ndarray]:
    """Policy observations at random cells and headings of plan A's true map (a third unknown), and its low map."""
    building = load_building("A")
    high, low = building.truth_codes(), building.coarsened(0.20).truth_codes()
    rng = np.random.default_rng(0)
    out = []
    for _ in range(count):
        seen = high.copy()
        seen[rng.random(seen.shape) < 0.3] = UNKNOWN
        row, col = int(rng.integers(high.shape[0])), int(rng.integers(high.shape[1]))
        yaw = float(rng.uniform(-math.pi, math.pi))
        out.append(observation_from_maps(seen, low, 0.05, 0.20, (row, col), (row // 4, col // 4), yaw, 0))
    return out, low


def fused_maps() -> VoxelMaps:
    """Plan A's daemon maps after a spin at three poses (24 frames)."""
    building = load_building("A")
    band = HeightBand()
    maps = VoxelMaps(VoxelRegion.covering(building.grid, *band_z_range_m(band)))
    camera = DepthCamera(building)
    x0, y0 = building.grid.origin_xy
    rows, cols = building.grid.shape
    r = building.grid.resolution_m
    stamp = 0.0
    for fx, fy in ((0.3, 0.5), (0.5, 0.5), (0.7, 0.4)):
        for yaw in np.linspace(0, 2 * math.pi, 8, endpoint=False):
            pose = CameraPose(x0 + fx * cols * r, y0 + fy * rows * r, 1.7, float(yaw))
            maps.fuse(
                camera.render(pose), camera.config.intrinsics, pose.position_m, pose.rotation_map_from_optical(), stamp
            )
            stamp += 0.1
    return maps


def timed_calls(
    calls: dict[str, Callable[[int], object]], before: Callable[[], object] | None, repeats: int
) -> dict[str, tuple[float, float, float]]:
    """(wall p50, wall p95, thread CPU p50) ms of each call, ``repeats`` times, ``before`` ahead of every one."""
    out = {}
    for name, call in calls.items():
        wall, cpu = np.empty(repeats), np.empty(repeats)
        for i in range(repeats):
            if before is not None:
                before()
            c0, w0 = time.thread_time(), time.perf_counter()
            call(i)
            wall[i], cpu[i] = time.perf_counter() - w0, time.thread_time() - c0
        out[name] = (1e3 * np.median(wall), 1e3 * np.percentile(wall, 95), 1e3 * np.median(cpu))
    return out


def node_profile(path: Path, feeds: list[dict[str, np.ndarray]], before: Callable[[], object], runs: int) -> str:
    """The policy graph's node time split (onnxruntime's profiler), one run after ``before`` each time."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.enable_profiling = True
    # onnxruntime writes its trace to ``<prefix>_<time>.json``, by default in the working directory (the repository
    # root): the trace goes into a temporary folder that is removed once read.
    with tempfile.TemporaryDirectory(prefix="edge-explorer-ort-profile-") as folder:
        options.profile_file_prefix = str(Path(folder) / "policy")
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        for i in range(runs):
            before()
            session.run(None, feeds[i % len(feeds)])
        events = json.loads(Path(session.end_profiling()).read_text())
    per_node: dict[str, list[float]] = {}
    ops, moved = {}, {}
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per_node.setdefault(e["name"], []).append(e["dur"])
            ops[e["name"]] = e["args"]["op_name"]
            moved[e["name"]] = int(e["args"].get("activation_size", 0)) + int(e["args"].get("output_size", 0))
    median = {name: float(np.median(d)) for name, d in per_node.items()}
    compute = sum(t for name, t in median.items() if ops[name] in COMPUTE_LAYERS)
    total = sum(median.values())
    return (
        f"{len(median)} nodes, node time {total / 1e3:.2f} ms (profiler on): convolutions + dense layers "
        f"{compute / 1e3:.2f} ms ({100 * compute / total:.0f} %), encoding / quantize / layout nodes "
        f"{(total - compute) / 1e3:.2f} ms ({100 * (total - compute) / total:.0f} %); activations read + written per "
        f"run {sum(moved.values()) / 1e6:.1f} MB"
    )


def session(path: Path, threads: int = 1, **settings: object) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = threads, 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    for key, value in settings.items():
        if key.startswith("session."):
            options.add_session_config_entry(key, str(value))
        else:
            setattr(options, key, value)
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models"))
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    obs, low = observations(32)
    policy = PolicyRuntime(load_model(args.models / "policy", ("onnxruntime-cpu",), "int8"))
    predictor = PredictorRuntime(load_model(args.models / "predictor", ("litert-cpu",), "int8"))
    robot = (low.shape[0] // 2, low.shape[1] // 2)
    path = policy.model.artifact
    dtypes = {spec.name: spec.dtype for spec in policy.model.backend.inputs}  # int8 codes, float32 one-hot
    feeds = [{k: np.asarray(o[k], dtypes[k]).reshape((1, *np.shape(o[k]))) for k in o} for o in obs]
    alone = session(path)
    maps, band = fused_maps(), HeightBand()
    calls = {
        "policy stage (PolicyRuntime.act)": lambda i: policy.act(obs[i % len(obs)]),
        "policy graph alone (session.run, inputs ready)": lambda i: alone.run(None, feeds[i % len(feeds)]),
        "project, 0.05 m map": lambda i: project(maps.high, band),
    }
    for call in calls.values():
        call(0)  # compile, allocate
    conditions: dict[str, Callable[[], object] | None] = {
        "back to back": None,
        "after the predictor": lambda: predictor.predict(low, robot),
        "after a 32 MB sweep": lambda: SWEEP_32MB.sum(),
        "after 50 ms sleep": lambda: time.sleep(0.05),
        "after 50 ms sleep + 20 ms computing": lambda: (time.sleep(0.05), spin_wait(0.02)),
    }
    print("| condition | call | wall p50 (ms) | wall p95 (ms) | thread CPU p50 (ms) |")
    print("| --- | --- | ---: | ---: | ---: |")
    for label, before in conditions.items():
        repeats = args.repeats // 5 if label.startswith("after 50 ms") else args.repeats
        for name, (p50, p95, cpu) in timed_calls(calls, before, repeats).items():
            print(f"| {label} | {name} | {p50:.3f} | {p95:.3f} | {cpu:.3f} |")
    after_predictor = conditions["after the predictor"]
    assert after_predictor is not None
    print("\npolicy graph, back to back:", node_profile(path, feeds, lambda: None, args.repeats))
    print("policy graph, after the predictor:", node_profile(path, feeds, after_predictor, args.repeats))
    variants = {
        "as the backend loads it": session(path),
        "memory arena off": session(path, enable_cpu_mem_arena=False),
        "memory pattern off": session(path, enable_mem_pattern=False),
        "spinning off": session(path, **{"session.intra_op.allow_spinning": 0}),
        "2 intra-op threads": session(path, threads=2),
        "2 intra-op threads, spinning off": session(path, threads=2, **{"session.intra_op.allow_spinning": 0}),
    }
    reference = [int(np.argmax(variants["as the backend loads it"].run(None, f)[0])) for f in feeds]
    for name, variant in variants.items():
        if [int(np.argmax(variant.run(None, f)[0])) for f in feeds] != reference:
            raise SystemExit(f"{name}: actions differ from the backend's session")
    runs = {name: (lambda i, s=s: s.run(None, feeds[i % len(feeds)])) for name, s in variants.items()}
    print("\n| onnxruntime session (after the predictor, same actions) | wall p50 (ms) | wall p95 (ms) |")
    print("| --- | ---: | ---: |")
    for name, (p50, p95, _) in timed_calls(runs, after_predictor, args.repeats).items():
        print(f"| {name} | {p50:.3f} | {p95:.3f} |")


if __name__ == "__main__":
    main()
