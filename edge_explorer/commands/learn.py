"""``edge-explorer train …`` and ``edge-explorer eval …``: the map predictor's and the goal policy's data, training
and shipping, and the predictor's evaluation.

Handlers import torch lazily, so ``edge-explorer --help`` works without the ``train`` extra.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

from edge_explorer.cli_support import positive_int
from edge_explorer.cluster.units import add_ray_argument
from edge_explorer.predict.calibration import DEFAULT_LEVELS

DESCRIPTION = (
    "Map predictor: collect training samples, train the U-Net, ship it with its model card. Goal policy: expert "
    "demonstrations, behaviour cloning (DAgger with --policy), MaskablePPO, ship it with its model card."
)


_DEMO_FLOOR_STEPS = 40_000  # the bench's step cap on whole floors (docs/bench/README.md)


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], got {value}")
    return value


def _threshold_pair(text: str) -> tuple[float, float]:
    """argparse type for ``T_F_MAX,T_O``: two probabilities with t_f_max ≤ t_o."""
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected T_F_MAX,T_O (e.g. 0.04,0.94), got {text!r}")
    t_f_max, t_o = (_probability(part) for part in parts)
    if t_f_max > t_o:
        raise argparse.ArgumentTypeError(f"need t_f_max ≤ t_o, got {text!r}")
    return t_f_max, t_o


def register(sub: argparse._SubParsersAction) -> None:
    train = sub.add_parser(
        "train",
        help="training: predictor-data, predictor, ship-predictor, calibrate-predictor, calibrate-probabilities, "
        "goal-demos, goal-bc, goal-ppo, ship-policy",
        description=DESCRIPTION,
    )
    tsub = train.add_subparsers(dest="train_command", metavar="WHAT", required=True)

    data = tsub.add_parser(
        "predictor-data",
        help="record partial maps while exploring the train/val plans (resumable)",
        description="Explore plans of the generated dataset and write predictor sample shards (.npz).",
    )
    data.add_argument("--plans", type=Path, default=Path("data/plans"), help="plan dataset (default data/plans)")
    data.add_argument(
        "--floors",
        action="store_true",
        help="explore the generated whole floors of each split (floor-SPLIT-K, 40-200 m) instead of the plan "
        "dataset: --train-plans / --val-plans count floors, moments are drawn over each flight's 6,000 steps",
    )
    data.add_argument("--out", type=Path, required=True, help="output folder (train/ and val/ shards)")
    data.add_argument(
        "--train-plans", type=_non_negative_int, default=4000, help="train plans to explore (4000; 0 = none)"
    )
    data.add_argument("--val-plans", type=_non_negative_int, default=300, help="val plans to explore (300; 0 = none)")
    data.add_argument(
        "--samples-per-plan",
        type=positive_int,
        default=None,
        help="moments recorded per plan (default 10 coverage levels; with --floors 40 steps)",
    )
    data.add_argument(
        "--plans-per-shard", type=positive_int, default=None, help="plans per shard (default 50; with --floors 1)"
    )
    data.add_argument("--seed", type=int, default=0)
    data.add_argument(
        "--noise-free-fraction",
        type=_probability,
        default=0.0,
        help="share of flights scanned with a noise-free sensor (default 0: every flight has the training noise)",
    )
    data.add_argument("--workers", type=positive_int, default=1, help="processes (default 1)")
    add_ray_argument(data)
    data.set_defaults(func=_predictor_data)

    pred = tsub.add_parser(
        "predictor",
        help="train the map predictor U-Net (BCE, AdamW; checkpoints, --resume)",
        description="Train the map predictor from a TOML config; see edge_explorer/learn/configs/predictor.toml. "
        "Under torchrun (--nproc_per_node N) it trains data-parallel with the same global batch (docs/cluster.md).",
    )
    pred.add_argument("--config", type=Path, required=True, help="TOML config")
    pred.add_argument("--out", type=Path, required=True, help="run folder: checkpoints, log.csv, best model")
    pred.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint (same config)")
    pred.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    pred.add_argument("--max-steps", type=positive_int, help="stop after N steps of this call (resume later)")
    pred.add_argument("--max-minutes", type=float, help="stop after this much wall time of this call (resume later)")
    pred.add_argument(
        "--loader-workers", type=int, default=0, help="processes that build the batches (same batches; feeds a GPU)"
    )
    pred.add_argument(
        "--precision",
        choices=("auto", "bf16", "fp32"),
        default="auto",
        help="forward pass in bfloat16 autocast: auto = on CUDA only (default); bf16 also on a CPU with native "
        "bfloat16 (AVX512-BF16/AMX: ~1.6x faster there); fp32 = never",
    )
    pred.set_defaults(func=_train_predictor)

    demos = tsub.add_parser(
        "goal-demos",
        help="fly the predictive expert (or, with --policy, a goal policy: DAgger) and record labelled decisions",
        description="Expert-labelled goal decisions on the generated plans, for the goal policy (resumable shards).",
    )
    demos.add_argument("--plans", default="data/plans", help="plan dataset (default data/plans)")
    demos.add_argument(
        "--floors",
        action="store_true",
        help="fly the generated whole floors of the split (floor-SPLIT-K, 40-200 m; one floor per shard) instead "
        "of the plan dataset",
    )
    demos.add_argument("--out", type=Path, required=True, help="shard folder")
    demos.add_argument("--split", choices=("train", "val"), default="train")
    demos.add_argument("--first", type=int, default=0, help="first plan index of the split (default 0)")
    demos.add_argument("--count", type=positive_int, required=True, help="plans to fly")
    demos.add_argument(
        "--max-steps",
        type=positive_int,
        default=None,
        help=f"step cap of a flight (default 1500, with --floors {_DEMO_FLOOR_STEPS:,}: a whole floor takes up to "
        "17,000 steps)",
    )
    demos.add_argument("--predictor", default="models/predictor", help="predictor reference ('' = none: phase 1)")
    demos.add_argument(
        "--policy",
        default=None,
        help="a goal policy to fly instead of the expert (DAgger): a .safetensors or an exported folder "
        "such as models/policy",
    )
    demos.add_argument("--workers", type=positive_int, default=1, help="processes (default 1)")
    demos.set_defaults(func=_goal_demos)

    bc = tsub.add_parser(
        "goal-bc",
        help="behaviour-clone the goal policy on expert demonstrations (checkpoints, --resume)",
        description="Train the goal policy network on expert-labelled decisions (masked cross-entropy).",
    )
    bc.add_argument("--train-demos", default="data/goal_demos/train", help="shard folder(s), comma-separated")
    bc.add_argument("--val-demos", default="data/goal_demos/val")
    bc.add_argument("--init", default="", help="goal-policy .safetensors to start from (default: random weights)")
    bc.add_argument("--steps", type=positive_int, default=4000, help="total optimizer steps (default 4000)")
    bc.add_argument("--batch-size", type=positive_int, default=32)
    bc.add_argument("--lr", type=float, default=1e-3, help="peak learning rate of the cosine schedule (default 1e-3)")
    bc.add_argument("--threads", type=positive_int, default=1)
    bc.add_argument("--device", default="cpu", help="torch device: cpu (default) or cuda (demonstrations on the GPU)")
    bc.add_argument(
        "--max-minutes", type=float, default=None, help="end this call with a checkpoint after M minutes (resumable)"
    )
    bc.add_argument("--out", type=Path, required=True, help="run folder")
    bc.add_argument("--resume", action="store_true", help="continue the run in OUT")
    bc.set_defaults(func=_goal_bc)

    ppo = tsub.add_parser(
        "goal-ppo",
        help="PPO (MaskablePPO) of the goal policy from its BC weights on the paper's reward (checkpoints, --resume)",
        description="MaskablePPO on the goal-selection environment; see edge_explorer/learn/train_goal_ppo.py.",
    )
    ppo.add_argument("--init", default="", help="GoalNet .safetensors to start from (the BC best.safetensors)")
    ppo.add_argument("--predictor", default="models/predictor", help="predictor ('' = phase 1: no predictor)")
    ppo.add_argument("--decisions", type=positive_int, default=20_000, help="total decisions (default 20000)")
    ppo.add_argument("--envs", type=positive_int, default=2, help="environment worker processes (default 2)")
    ppo.add_argument("--train-plans", type=positive_int, default=2000, help="train plans the envs share (2000)")
    ppo.add_argument(
        "--eval-plans", type=positive_int, default=10, help="val plans per evaluation (10; more select better)"
    )
    ppo.add_argument("--out", type=Path, required=True, help="run folder")
    ppo.add_argument("--resume", action="store_true", help="continue the run in OUT")
    add_ray_argument(ppo)
    ppo.set_defaults(func=_goal_ppo)

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
    ship.add_argument(
        "--whole-floors",
        action="store_true",
        help="the model also learned whole floors (train predictor-data --floors): its card says so (envelope_m "
        "null) and no envelope limits its OCCUPIED predictions in flight",
    )
    ship.set_defaults(func=_ship_predictor)

    cal = tsub.add_parser(
        "calibrate-predictor",
        help="choose the predictor's thresholds t_f_max, t_o on the val split for a precision target; into its card",
        description="Fly plans of the regenerated val split as eval predictor does, score every (t_f_max, t_o) pair "
        "by the precision of the cells the thresholded prediction claims and the coverage it adds, and write the "
        "chosen pair into the model card (only if it meets the target); table and reliability curve to --docs.",
    )
    cal.add_argument("--model", type=Path, default=Path("models/predictor"), help="exported model folder (card.json)")
    cal.add_argument("--plans", type=positive_int, default=40, help="val plans to fly (default 40)")
    cal.add_argument("--target", type=_probability, default=0.95, help="precision target (default 0.95)")
    cal.add_argument(
        "--levels",
        type=_probability,
        nargs="+",
        default=list(DEFAULT_LEVELS),
        help="true coverage levels to sample at; the target holds at each (default %(default)s)",
    )
    cal.add_argument("--explorer", default="random-goal", help="random-goal (default), frontier or fuel")
    cal.add_argument("--seed", type=int, default=0)
    cal.add_argument(
        "--occupied-noise", type=_probability, default=0.1, metavar="P", help="sensor noise (default 0.1, as eval)"
    )
    cal.add_argument("--docs", type=Path, default=Path("docs/predictor"), help="calibration_val.json / .png here")
    cal.set_defaults(func=_calibrate_predictor)

    prob = tsub.add_parser(
        "calibrate-probabilities",
        help="fit a monotone map that calibrates the predictor's P(occupied) on the val split; into its card",
        description="Fly plans of the regenerated val split as eval predictor does (raw model), count every "
        "unobserved interior cell of the window with its probability and truth, fit a strictly increasing map "
        "(beta calibration sigmoid(a ln p - c ln(1-p) + b), or platt: a = c) by maximum likelihood, check that no "
        "thresholded map changes (the card's thresholds are mapped with it), and write it into the card as "
        "'calibration'; PredictorRuntime then hands out calibrated probabilities. Figures to --docs "
        "(probability_calibration_val.json, reliability_val.png). Measure on test with eval predictor "
        "--reliability-plot.",
    )
    prob.add_argument("--model", type=Path, default=Path("models/predictor"), help="exported model folder (card.json)")
    prob.add_argument("--plans", type=positive_int, default=12, help="val plans to fly (default 12)")
    prob.add_argument("--method", choices=("beta", "platt"), default="beta", help="the map (default beta)")
    prob.add_argument("--bins", type=positive_int, default=20, help="reliability bins for the report (default 20)")
    prob.add_argument("--explorer", default="random-goal", help="random-goal (default), frontier or fuel")
    prob.add_argument("--seed", type=int, default=0)
    prob.add_argument(
        "--occupied-noise", type=_probability, default=0.1, metavar="P", help="sensor noise (default 0.1, as eval)"
    )
    prob.add_argument("--docs", type=Path, default=Path("docs/predictor"), help="figures here")
    prob.set_defaults(func=_calibrate_probabilities)

    ship_pol = tsub.add_parser(
        "ship-policy",
        help="copy goal-policy weights to models/policy with card.json (stages, evaluation, flight-ready)",
        description="Write the shipped goal policy and its model card from its training stages and the benchmark "
        "that flew these weights; then `edge-explorer export --recipe quantize/policy.toml` adds the artifacts.",
    )
    ship_pol.add_argument("--weights", type=Path, required=True, help="goal-policy .safetensors (a run's best)")
    ship_pol.add_argument(
        "--stage", type=Path, action="append", default=[], help="a training run folder (goal-bc / goal-ppo), in order"
    )
    ship_pol.add_argument("--out", type=Path, default=Path("models/policy"))
    ship_pol.add_argument("--eval", type=Path, help="the bench explore --json report that flew these weights")
    ship_pol.add_argument("--docs", type=Path, default=Path("docs/policy"), help="learning curves here")
    ship_pol.add_argument("--command", default="", help="the training command lines, for the card")
    ship_pol.set_defaults(func=_ship_policy)

    ev = sub.add_parser(
        "eval",
        help="evaluation: predictor (the policy: bench explore --methods drl+pred)",
        description="Evaluate trained models.",
    )
    esub = ev.add_subparsers(dest="eval_command", metavar="WHAT", required=True)
    evp = esub.add_parser(
        "predictor",
        help="F1 / coverage / correct coverage of observed + thresholded prediction vs true coverage",
        description="Explore each plan with a fixed-seed explorer and score the map with the prediction at every "
        "step (docs/design.md §5, §7).",
    )
    evp.add_argument(
        "--model", type=Path, required=True, help="weights (.safetensors) or an exported model folder (card.json)"
    )
    evp.add_argument("--plans", required=True, help="plan reference: test, A-D, a folder, a .yaml/.json")
    evp.add_argument("--json", type=Path, required=True, help="write the figures here")
    evp.add_argument("--plot", type=Path, help="curves (PNG)")
    evp.add_argument(
        "--reliability-plot",
        type=Path,
        metavar="PNG",
        help="reliability diagram of the unobserved interior cells (raw, and calibrated if the card calibrates); "
        "ECE / MCE / Brier are always in --json under 'reliability'",
    )
    evp.add_argument("--explorer", default="random-goal", help="random-goal (default), frontier or fuel")
    evp.add_argument("--seed", type=int, default=0)
    evp.add_argument("--limit", type=positive_int, help="only the first N plans")
    evp.add_argument(
        "--occupied-noise",
        type=_probability,
        default=0.1,
        metavar="P",
        help="sensor noise: probability that each neighbour of a detected wall is labelled occupied (default 0.1, "
        "as in training; 0 shows what the noise costs)",
    )
    evp.add_argument(
        "--thresholds",
        type=_threshold_pair,
        metavar="T_F_MAX,T_O",
        help="score with these thresholds instead of the model's own (its card's calibrated pair, else the "
        "defaults 0.04,0.94): compare models or thresholds like for like",
    )
    add_ray_argument(evp)
    evp.set_defaults(func=_eval_predictor)


def _goal_demos(args: argparse.Namespace) -> int:
    from edge_explorer.learn.goal_demos import DemoConfig, generate_demos

    config = (
        DemoConfig()
        if args.max_steps is None and not args.floors
        else DemoConfig(max_steps=args.max_steps or _DEMO_FLOOR_STEPS)
    )
    decisions = generate_demos(
        args.plans,
        args.out,
        args.split,
        (args.first, args.first + args.count),
        args.predictor or None,
        args.policy,
        plans_per_shard=1 if args.floors else 10,
        workers=args.workers,
        config=config,
        floors=args.floors,
    )
    print(f"{decisions} labelled decisions written to {args.out}")
    return 0


def _goal_bc(args: argparse.Namespace) -> int:
    from edge_explorer.learn.train_goal_bc import BCConfig, train

    config = BCConfig(
        train_demos=args.train_demos,
        val_demos=args.val_demos,
        total_steps=args.steps,
        batch_size=args.batch_size,
        threads=args.threads,
        init=args.init,
        learning_rate=args.lr,
        device=args.device,
    )
    state = train(config, args.out, resume=args.resume, max_minutes=args.max_minutes)
    print(f"step {state['step']}: best val agreement with the expert {state['best_agreement']:.3f} → {args.out}")
    return 0


def _goal_ppo(args: argparse.Namespace) -> int:
    from edge_explorer.learn.train_goal_ppo import PPOConfig, train

    config = PPOConfig(
        init_weights=args.init,
        predictor=args.predictor,
        total_decisions=args.decisions,
        n_envs=args.envs,
        train_plans=args.train_plans,
        eval_plans=args.eval_plans,
    )
    decisions = train(config, args.out, resume=args.resume, ray=args.ray)
    print(f"{decisions} decisions trained → {args.out} (best.safetensors, val_log.csv)")
    return 0


def _non_negative_int(text: str) -> int:
    """argparse type for a count that may be 0."""
    return 0 if text.strip() == "0" else positive_int(text)


def _predictor_data(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.learn.predictor_data import FLOOR_SAMPLES, SampleConfig, generate_predictor_data

    config = dataclasses.replace(
        FLOOR_SAMPLES if args.floors else SampleConfig(samples_per_plan=10),
        seed=args.seed,
        noise_free_fraction=args.noise_free_fraction,
    )
    if args.samples_per_plan is not None:
        config = dataclasses.replace(config, samples_per_plan=args.samples_per_plan)
    counts = {split: n for split, n in (("train", args.train_plans), ("val", args.val_plans)) if n > 0}
    if not counts:
        raise EdgeExplorerError("--train-plans and --val-plans are both 0: nothing to explore")
    report = generate_predictor_data(
        args.plans,
        args.out,
        counts,
        config,
        args.plans_per_shard or (1 if args.floors else 50),
        args.workers,
        args.ray,
        floors=args.floors,
    )
    print(
        f"{report.samples} samples from {report.plans} plans in {report.seconds:.0f} s "
        f"({report.shards_done_before} shards were already done) → {args.out}"
    )
    return 0


def _train_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.learn.train_predictor import load_config, train

    if args.loader_workers < 0 or (args.max_minutes is not None and args.max_minutes <= 0):
        raise EdgeExplorerError("--loader-workers must be ≥ 0 and --max-minutes > 0")
    state = train(
        load_config(args.config),
        args.out,
        args.resume,
        args.device,
        args.config,
        args.max_steps,
        loader_workers=args.loader_workers,
        max_minutes=args.max_minutes,
        precision=args.precision,
    )
    if os.environ.get("RANK", "0") != "0":
        return 0  # under torchrun, rank 0 reports
    print(
        f"step {state.step}: {state.samples} samples, {state.wall_s / 3600:.2f} h of training; best val score "
        f"{state.best_score:.4f} (mean F1 from 50 % coverage up) at step {state.best_step} → "
        f"{args.out / 'best.safetensors'}"
    )
    return 0


def _ship_policy(args: argparse.Namespace) -> int:
    from edge_explorer.learn.goal_card import ship_goal_policy

    card = ship_goal_policy(args.weights, args.stage, args.out, args.eval, args.command, args.docs)
    arch = card["architecture"]
    print(
        f"{args.out / card['weights']}: {arch['macs'] / 1e6:.0f} MMAC, {arch['params'] / 1e6:.3f} M params, "
        f"{card['latency_torch_fp32_this_host']['median_ms']:.1f} ms fp32 single-thread; "
        f"sha256 {card['sha256'][:12]}…; flight-ready: {card['flight_ready']['ready']} ({card['flight_ready']['why']})"
    )
    return 0


def _calibrate_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.learn.calibrate_predictor import calibrate_cli

    return calibrate_cli(args)


def _calibrate_probabilities(args: argparse.Namespace) -> int:
    from edge_explorer.learn.calibrate_probabilities import calibrate_probabilities_cli

    return calibrate_probabilities_cli(args)


def _ship_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.learn.predictor_card import ship_predictor

    evaluations = {}
    for item in args.eval:
        name, sep, path = item.partition("=")
        if not sep:
            raise EdgeExplorerError(f"--eval expects NAME=JSON, got {item!r}")
        evaluations[name] = Path(path)
    card = ship_predictor(args.run, args.out, evaluations, args.command, args.whole_floors)
    print(
        f"{args.out / card['weights']}: {card['architecture']['macs'] / 1e9:.2f} GMAC, "
        f"{card['architecture']['params'] / 1e6:.2f} M params, "
        f"{card['latency_torch_fp32_this_host']['median_ms']:.1f} ms fp32 single-thread; sha256 {card['sha256'][:12]}…"
    )
    return 0


def _eval_predictor(args: argparse.Namespace) -> int:
    from edge_explorer.learn.eval_predictor import evaluate_cli

    return evaluate_cli(args)
