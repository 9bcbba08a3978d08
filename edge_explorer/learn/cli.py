"""``edge-explorer train …`` and ``edge-explorer eval …``: the map predictor's data, training and evaluation.

Handlers import torch lazily, so ``edge-explorer --help`` works without the ``train`` extra.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = "Map predictor: collect training samples, train the U-Net, ship it with its model card."


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def register(sub: argparse._SubParsersAction) -> None:
    train = sub.add_parser("train", help="training: predictor-data, predictor, ship-predictor", description=DESCRIPTION)
    tsub = train.add_subparsers(dest="train_command", metavar="WHAT", required=True)

    data = tsub.add_parser(
        "predictor-data",
        help="record partial maps while exploring the train/val plans (resumable)",
        description="Explore plans of the generated dataset and write predictor sample shards (.npz).",
    )
    data.add_argument("--plans", type=Path, default=Path("data/plans"), help="plan dataset (default data/plans)")
    data.add_argument("--out", type=Path, required=True, help="output folder (train/ and val/ shards)")
    data.add_argument("--train-plans", type=_positive_int, default=4000, help="train plans to explore (4000)")
    data.add_argument("--val-plans", type=_positive_int, default=300, help="val plans to explore (300)")
    data.add_argument("--samples-per-plan", type=_positive_int, default=10, help="coverage levels per plan (10)")
    data.add_argument("--plans-per-shard", type=_positive_int, default=50)
    data.add_argument("--seed", type=int, default=0)
    data.add_argument("--workers", type=_positive_int, default=1, help="processes (default 1)")
    data.set_defaults(func=_predictor_data)

    pred = tsub.add_parser(
        "predictor",
        help="train the map predictor U-Net (BCE, AdamW; checkpoints, --resume)",
        description="Train the map predictor from a TOML config; see edge_explorer/learn/configs/predictor.toml.",
    )
    pred.add_argument("--config", type=Path, required=True, help="TOML config")
    pred.add_argument("--out", type=Path, required=True, help="run folder: checkpoints, log.csv, best model")
    pred.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint (same config)")
    pred.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    pred.add_argument("--max-steps", type=_positive_int, help="stop after N steps of this call (resume later)")
    pred.set_defaults(func=_train_predictor)

    ship = tsub.add_parser(
        "ship-predictor",
        help="copy a run's best weights to models/predictor with card.json (sha256, MACs, metrics, latency)",
        description="Write the shipped predictor and its model card from a training run and its evaluations.",
    )
    ship.add_argument("--run", type=Path, required=True, help="training run folder (best.safetensors)")
    ship.add_argument("--out", type=Path, default=Path("models/predictor"))
    ship.add_argument(
        "--eval", action="append", default=[], metavar="NAME=JSON", help="an eval predictor JSON of these weights"
    )
    ship.add_argument("--command", default="", help="the training command line, for the card")
    ship.set_defaults(func=_ship_predictor)

    ev = sub.add_parser("eval", help="evaluation: predictor", description="Evaluate trained models.")
    esub = ev.add_subparsers(dest="eval_command", metavar="WHAT", required=True)
    evp = esub.add_parser(
        "predictor",
        help="F1 / coverage / correct coverage of observed + thresholded prediction vs true coverage",
        description="Explore each plan with a fixed-seed explorer and score the map with the prediction at every "
        "step (DESIGN.md §5, §7).",
    )
    evp.add_argument(
        "--model", type=Path, required=True, help="weights (.safetensors) or an exported model folder (card.json)"
    )
    evp.add_argument("--plans", required=True, help="plan reference: test, A-D, a folder, a .yaml/.json")
    evp.add_argument("--json", type=Path, required=True, help="write the figures here")
    evp.add_argument("--plot", type=Path, help="curves (PNG)")
    evp.add_argument("--explorer", default="random-goal", help="random-goal (default), frontier or fuel")
    evp.add_argument("--seed", type=int, default=0)
    evp.add_argument("--limit", type=_positive_int, help="only the first N plans")
    evp.set_defaults(func=_eval_predictor)


def _predictor_data(args: argparse.Namespace) -> int:
    from edge_explorer.learn.predictor_data import SampleConfig, generate_predictor_data

    config = SampleConfig(samples_per_plan=args.samples_per_plan, seed=args.seed)
    report = generate_predictor_data(
        args.plans,
        args.out,
        {"train": args.train_plans, "val": args.val_plans},
        config,
        args.plans_per_shard,
        args.workers,
    )
    print(
        f"{report.samples} samples from {report.plans} plans in {report.seconds:.0f} s "
        f"({report.shards_done_before} shards were already done) → {args.out}"
    )
    return 0


def _train_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.learn.train_predictor import load_config, train

    state = train(load_config(args.config), args.out, args.resume, args.device, args.config, args.max_steps)
    print(
        f"step {state.step}: {state.samples} samples, {state.wall_s / 3600:.2f} h of training; best val score "
        f"{state.best_score:.4f} (mean F1 from 50 % coverage up) at step {state.best_step} → "
        f"{args.out / 'best.safetensors'}"
    )
    return 0


def _ship_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.learn.predictor_card import ship_predictor

    evaluations = {}
    for item in args.eval:
        name, sep, path = item.partition("=")
        if not sep:
            raise EdgeExplorerError(f"--eval expects NAME=JSON, got {item!r}")
        evaluations[name] = Path(path)
    card = ship_predictor(args.run, args.out, evaluations, args.command)
    print(
        f"{args.out / card['weights']}: {card['architecture']['macs'] / 1e9:.2f} GMAC, "
        f"{card['architecture']['params'] / 1e6:.2f} M params, "
        f"{card['latency_torch_fp32_this_host']['median_ms']:.1f} ms fp32 single-thread; sha256 {card['sha256'][:12]}…"
    )
    return 0


def _eval_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.learn.eval_predictor import evaluate_cli

    return evaluate_cli(args)
