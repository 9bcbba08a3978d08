"""``edge-explorer sim …``: measure the training simulator's speed and look at its episodes."""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path
from typing import Any

from edge_explorer.cli_support import positive_int

DESCRIPTION = "2-D exploration simulator: benchmark its step rate, draw an episode."


def register(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("sim", help="simulator: bench, show", description=DESCRIPTION)
    ssub = sim.add_subparsers(dest="sim_command", metavar="ACTION", required=True)

    bench = ssub.add_parser(
        "bench",
        help="env steps per second on one core, no predictor, full-size observations",
        description="Random actions on the given plans; one process, one thread; time per stage.",
    )
    bench.add_argument("--steps", type=positive_int, required=True, help="timed env steps")
    bench.add_argument("--plans", default="A,B,C,D", help="plan reference(s) (default: the bundled A,B,C,D)")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--warmup", type=int, default=200, help="untimed steps first (default 200)")
    bench.add_argument("--json", type=Path, help="write the figures here")
    bench.set_defaults(func=_bench)

    show = ssub.add_parser("show", help="run one episode and draw the observation beside the truth")
    show.add_argument("--plan", required=True, help="one plan: A-D, a plan .json or a map_server .yaml")
    show.add_argument("--steps", type=positive_int, required=True, help="at most this many steps")
    show.add_argument("--png", type=Path, required=True, help="the last observation beside the truth")
    show.add_argument("--gif", type=Path, help="also an animation of every step")
    show.add_argument(
        "--policy",
        choices=("scripted", "random"),
        default="scripted",
        help="scripted: fly forward, turn away from walls (default); random: uniform actions",
    )
    show.add_argument("--seed", type=int, default=0)
    show.set_defaults(func=_show)


def _bench(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np
    from tqdm import tqdm

    from edge_explorer.cli_support import write_json
    from edge_explorer.sim.env import STAGES, ExplorationEnv
    from edge_explorer.world.catalog import load_buildings

    cv2.setNumThreads(1)  # one core: opencv would otherwise use a thread pool for the warps
    plans = load_buildings(args.plans)
    env = ExplorationEnv(plans)
    rng = np.random.default_rng(args.seed)
    env.reset(seed=args.seed)
    for _ in range(args.warmup):  # compiles/loads the numba kernels, warms the caches
        _, _, terminated, truncated, _ = env.step(int(rng.integers(6)))
        if terminated or truncated:
            env.reset()
    env.stage_seconds.update(dict.fromkeys(STAGES, 0.0))
    actions = rng.integers(6, size=args.steps)
    episodes = 0
    reset_s = 0.0
    start = time.perf_counter()
    for action in tqdm(actions, desc="sim bench", unit="step", mininterval=1.0):
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            t = time.perf_counter()
            env.reset()
            reset_s += time.perf_counter() - t
            episodes += 1
    total_s = time.perf_counter() - start
    stages = dict(env.stage_seconds)
    stages["reset"] = reset_s
    stages["other"] = total_s - sum(stages.values())  # env bookkeeping, action sampling, loop
    report: dict[str, Any] = {
        "steps": args.steps,
        "seconds": total_s,
        "steps_per_s": args.steps / total_s,
        "us_per_step": 1e6 * total_s / args.steps,
        "plans": [p.name for p in plans],
        "episodes_finished": episodes,
        "predictor": None,
        "observation_shapes": {k: list(v.shape) for k, v in env.observation_space.spaces.items()},
        "stages": {name: {"us_per_step": 1e6 * s / args.steps, "share": s / total_s} for name, s in stages.items()},
        "dominant_stage": max(env.stage_seconds, key=env.stage_seconds.get),  # type: ignore[arg-type]
        "host": {
            "machine": platform.machine(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "load_average_1min": os.getloadavg()[0],
            "threads": "1 (cv2.setNumThreads(1); numba kernels are serial)",
        },
    }
    print(
        f"{report['steps_per_s']:.0f} env steps/s ({report['us_per_step']:.0f} µs/step) over {args.steps} steps "
        f"on {','.join(report['plans'])}; {episodes} episodes ended"
    )
    for name, figures in report["stages"].items():
        print(f"  {name:15s} {figures['us_per_step']:7.1f} µs/step  {100 * figures['share']:5.1f} %")
    write_json(args.json, report)
    return 0


def _scripted_action(obs: dict[str, Any], rng: Any, turn: int) -> tuple[int, int]:
    """Fly forward while the inflated map is clear 0.75 m ahead, else keep turning one way; returns (action, turn).

    A demonstration policy for ``sim show``, not an explorer: it wanders and turns away from what it sees.
    """
    from edge_explorer.vehicle.dynamics import Action
    from edge_explorer.world.grid import NON_FLIGHT, OCCUPIED

    high = obs["high"]
    c = high.shape[0] // 2
    ahead = high[c + 1 : c + 16, c - 1 : c + 2]  # heading is +row; the band already holds the robot radius
    if ((ahead == OCCUPIED) | (ahead == NON_FLIGHT)).any():
        turn = turn or int(rng.choice([-1, 1]))
        return (Action.TURN_LEFT if turn > 0 else Action.TURN_RIGHT), turn
    u = rng.random()
    if u < 0.1:
        return Action.TURN_LEFT_FORWARD, 0
    if u < 0.2:
        return Action.TURN_RIGHT_FORWARD, 0
    return Action.FORWARD, 0


def _show(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch
    from PIL import Image
    from tqdm import tqdm

    from edge_explorer.sim.env import ExplorationEnv
    from edge_explorer.world.catalog import load_building

    raster = load_building(args.plan)
    env = ExplorationEnv([raster], render_mode="rgb_array")
    rng = np.random.default_rng(args.seed)
    obs, info = env.reset(seed=args.seed)
    frames = [env.render()] if args.gif else []
    turn = 0
    for _ in tqdm(range(args.steps), desc="sim show", unit="step", mininterval=1.0):
        if args.policy == "random":
            action = int(rng.integers(6))
        else:
            action, turn = _scripted_action(obs, rng, turn)
        obs, _, terminated, truncated, info = env.step(action)
        if args.gif:
            frames.append(env.render())
        if terminated or truncated:
            break

    codes_cmap = ListedColormap(["white", "0.55", "black", "orange"])  # FREE, UNKNOWN, OCCUPIED, NON_FLIGHT
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.6), gridspec_kw={"width_ratios": [1, 1, 1.7]})
    half = obs["high"].shape[0] // 2
    for ax, key, res in ((axes[0], "high", 0.05), (axes[1], "thres", 0.20)):
        extent = np.array([-half - 0.5, half + 0.5]) * res
        ax.imshow(
            obs[key],
            origin="lower",
            cmap=codes_cmap,
            vmin=-1.5,
            vmax=2.5,
            interpolation="nearest",
            extent=(*extent, *extent),
        )
        ax.plot(0, 0, marker="^", color="red", markersize=8)
        ax.set_title(f"observation '{key}' ({res:.2f} m cells, heading up)")
        ax.set_xlabel("right of the vehicle [m]")
        ax.set_ylabel("ahead of the vehicle [m]")
    grid = raster.grid
    x0, y0 = grid.origin_xy
    axes[2].imshow(
        env.truth_image(), extent=(x0, x0 + grid.size_xy_m[0], y0, y0 + grid.size_xy_m[1]), interpolation="nearest"
    )
    axes[2].plot(*env.path_xy_m[0], marker="o", color="green", markersize=6)
    axes[2].set_title(
        f"truth {raster.name}: coverage {info['coverage']:.2f}, F1 {info['f1']:.2f}, "
        f"path {info['path_length_m']:.1f} m, {info['steps']} steps"
    )
    axes[2].set_xlabel("x [m]")
    axes[2].set_ylabel("y [m]")
    axes[2].legend(
        handles=[
            Patch(fc="white", ec="0.6", label="observation: free"),
            Patch(color="0.55", label="observation: unknown"),
            Patch(color="black", label="occupied (observed)"),
            Patch(color="orange", label="observation: non-flight band"),
            Patch(color=(170 / 255, 210 / 255, 250 / 255), label="truth panel: observed free"),
            Patch(color=(150 / 255,) * 3, label="truth panel: wall not yet seen"),
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.12),
        ncol=3,
        fontsize=8,
    )
    fig.tight_layout()
    args.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=110)
    plt.close(fig)
    if args.gif:
        args.gif.parent.mkdir(parents=True, exist_ok=True)
        images = [Image.fromarray(f) for f in frames]
        images[0].save(args.gif, save_all=True, append_images=images[1:], duration=200, loop=0)
    print(
        f"{raster.name}: {info['steps']} steps, coverage {info['coverage']:.3f}, F1 {info['f1']:.3f}, "
        f"path {info['path_length_m']:.1f} m → {args.png}" + (f", {args.gif}" if args.gif else "")
    )
    return 0
