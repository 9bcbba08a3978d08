"""``edge-explorer profile``: will the stack fit on my board? Measured here, estimated there, PASS/FAIL per budget.

Runs the daemon's real loop against the simulated vehicle (:mod:`edge_explorer.profiling.loop`), then every
shipped model on every backend available here (:mod:`edge_explorer.profiling.models`), and writes
``report.json`` (:mod:`edge_explorer.profiling.report`) + ``report.html`` (:mod:`edge_explorer.profiling.html_report`)
to ``--out`` with a section per ``--profile``; a Markdown summary goes to the terminal. The ``host`` profile
describes the machine the measurements come from and is the reference every estimate is scaled from. Each model runs
in the loop on the first backend of the host profile's order for it (``[backends]``). ``--record DIR`` keeps the
flight's frames, poses and per-call timings for ``scripts/independent_check.py``; ``--replay DIR`` flies with
those frames instead of rendering them.
Exit code 0 whatever the verdicts (they are the report's content).
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
from pathlib import Path

from edge_explorer.cli_support import positive_int

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
HOST_PROFILE = "host"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "profile",
        help="latency profiling report against device budgets (host measured, other devices estimated)",
        description=__doc__.splitlines()[0],
    )
    p.add_argument(
        "--profile",
        action="append",
        metavar="NAME|PATH",
        help="device profile (a name in profiles/ or a .toml); repeat for several (default: host)",
    )
    p.add_argument(
        "--backend",
        action="append",
        metavar="NAME",
        help="only these backends (repeatable): edgetpu, litert-cpu, onnxruntime-cpu, here and in every profile's "
        "order (default: all; each device tries them in its profile's order)",
    )
    p.add_argument(
        "--decisions", type=positive_int, default=60, metavar="N", help="measured decisions of the loop (default 60)"
    )
    p.add_argument(
        "--warmup", type=int, default=5, metavar="N", help="decisions (and model runs) discarded first (default 5)"
    )
    p.add_argument(
        "--model-runs",
        type=positive_int,
        default=100,
        metavar="N",
        help="timed runs per model and backend (default 100)",
    )
    p.add_argument("--plan", metavar="PLAN", help="the simulated building (default: the --replay recording's, else A)")
    p.add_argument(
        "--models", type=Path, default=MODELS_DIR, metavar="DIR", help=f"model folder (default {MODELS_DIR})"
    )
    p.add_argument("--out", type=Path, default=Path("runs/profile"), metavar="DIR", help="output folder")
    p.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="also record every fused depth frame with its pose and the loop's per-call timings into DIR (about "
        "100 kB a frame), for scripts/independent_check.py to replay the same calls",
    )
    p.add_argument(
        "--replay",
        type=Path,
        metavar="DIR",
        help="take the depth frames and their poses from a --record folder instead of rendering them (the same "
        "fuse calls without the simulated camera's work in the process)",
    )
    p.set_defaults(func=_profile)


def _profile(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from edge_explorer.backends.chain import BACKENDS
    from edge_explorer.cli_support import write_json
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.profiling.html_report import write_html
    from edge_explorer.profiling.loop import RECORDED_TIMINGS, LoopOptions, measure_loop
    from edge_explorer.profiling.models import bench_models
    from edge_explorer.profiling.report import build_report, markdown_summary
    from edge_explorer.runtime.device_profile import load_profile

    if args.warmup < 0:
        raise EdgeExplorerError(f"--warmup must be ≥ 0, got {args.warmup}")
    if args.record is not None and args.record.exists() and not args.record.is_dir():
        raise EdgeExplorerError(f"--record {args.record}: exists and is not a folder; name a (new) folder")
    plan = args.plan or "A"
    if args.replay is not None:
        if args.record is not None and args.record.resolve() == args.replay.resolve():
            raise EdgeExplorerError("--record and --replay name the same folder: record into another one")
        recorded = args.replay / RECORDED_TIMINGS
        if args.plan is None and recorded.is_file():
            plan = json.loads(recorded.read_text())["plan"]
    host = load_profile(HOST_PROFILE)
    if not host.measured:
        raise EdgeExplorerError(f"profiles/{HOST_PROFILE}.toml must say measured = true: it describes this machine")
    profiles = [load_profile(p) for p in (args.profile or [HOST_PROFILE])]
    backends = tuple(args.backend or BACKENDS)
    unknown = [b for b in backends if b not in BACKENDS]
    if unknown:
        raise EdgeExplorerError(f"--backend {unknown[0]!r}: choose from {', '.join(BACKENDS)}")
    here = host.restricted_to(backends)
    if args.backend:  # every device is then assumed to run only these backends, in its own order
        profiles = [p.restricted_to(backends) for p in profiles]
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    options = LoopOptions(
        models_dir=args.models,
        backend_order=here.backend_order or backends,
        model_orders={model: order or backends for model, order in here.model_orders.items()},
        record_dir=args.record,
        replay_dir=args.replay,
        plan=plan,
        decisions=args.decisions,
        warmup_decisions=args.warmup,
        depth_hz=host.rates_hz.depth,
        setpoint_hz=max(host.rates_hz.setpoint, 10.0),
    )
    with tqdm(total=args.warmup + args.decisions, desc="daemon loop (decisions)", unit="dec") as bar:
        loop = measure_loop(options, bar.update)
    with tqdm(desc="models × backends", unit="run") as bar:
        models = bench_models(
            args.models, backends, args.model_runs, max(args.warmup, 1), on_run=lambda label: _step(bar, label)
        )
    command = "edge-explorer " + shlex.join(sys.argv[1:]) if Path(sys.argv[0]).name == "edge-explorer" else ""
    doc = build_report(host, profiles, loop, models, command or "edge-explorer profile (called from Python)")
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "report.json", doc)
    write_html(args.out / "report.html", doc, loop.samples_ms)
    print(markdown_summary(doc))
    print(f"\nreport: {args.out / 'report.html'}, {args.out / 'report.json'}")
    return 0


def _step(bar: object, label: str) -> None:
    bar.set_postfix_str(label)  # type: ignore[attr-defined]
    bar.update(1)  # type: ignore[attr-defined]
