"""``edge-explorer plans …``: generate the dataset, look at plans, check plan files."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from edge_explorer.cli_support import positive_int
from edge_explorer.cluster.units import add_ray_argument

DESCRIPTION = "Floor plans: generate the dataset, show a plan, check plan files, draw a contact sheet."


def _split_arg(text: str) -> tuple[int, int, int]:
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--split must be three integers like 45000,4900,100, got {text!r}") from None
    if len(values) != 3 or min(values) < 0 or sum(values) == 0:
        raise argparse.ArgumentTypeError(f"--split must be three non-negative integers, got {text!r}")
    return values  # type: ignore[return-value]


def register(sub: argparse._SubParsersAction) -> None:
    plans = sub.add_parser("plans", help="floor plans: generate, show, check, sheet", description=DESCRIPTION)
    psub = plans.add_subparsers(dest="plans_command", metavar="ACTION", required=True)

    gen = psub.add_parser("generate", help="generate the sharded dataset (parallel, resumable)")
    gen.add_argument("--count", type=positive_int, required=True, help="total number of plans")
    gen.add_argument("--seed", type=int, default=0, help="dataset seed (default 0, the one the test split uses)")
    gen.add_argument("--out", type=Path, required=True, help="output folder (resumes if it exists)")
    gen.add_argument("--split", type=_split_arg, default=(45000, 4900, 100), help="train,val,test ratio")
    gen.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1, help="processes (default: all cores)")
    add_ray_argument(gen)
    gen.add_argument("--json", type=Path, help="write the run's figures here")
    gen.set_defaults(func=_generate)

    show = psub.add_parser("show", help="draw one plan to a PNG")
    show.add_argument("plan", help="A-D, a plan .json, or a map_server .yaml")
    show.add_argument("--png", type=Path, required=True)
    show.set_defaults(func=_show)

    check = psub.add_parser("check", help="load and validate plans; print their size and N_M")
    check.add_argument("plans", help="plan reference(s): A,B, test, a file, or a folder")
    check.add_argument("--json", type=Path)
    check.set_defaults(func=_check)

    sheet = psub.add_parser("sheet", help="contact sheet of random generated plans (+ extra plans)")
    sheet.add_argument("--count", type=positive_int, default=24)
    sheet.add_argument("--seed", type=int, default=0)
    sheet.add_argument("--extra", help="more plans to append, e.g. a folder of map_server .yaml plans")
    sheet.add_argument("--plans", help="draw these plans instead of random generated ones, e.g. floors-test")
    sheet.add_argument("--png", type=Path, required=True)
    sheet.set_defaults(func=_sheet)


def _generate(args: argparse.Namespace) -> int:
    from edge_explorer.cli_support import write_json
    from edge_explorer.world.dataset import generate_dataset

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    report = generate_dataset(args.out, args.count, args.seed, args.split, args.workers, args.ray)
    for s in report.skipped:
        print(f"skipped {s['index']} (seed {s['seed']}): {s['error']}", file=sys.stderr)
    engine = f"Ray {args.ray}" if args.ray else f"{args.workers} workers"
    print(
        f"{report.plans} plans generated and validated in {report.seconds:.1f} s "
        f"({report.plans_per_s:.1f} plans/s, {engine}); {len(report.skipped)} seeds skipped; "
        f"{report.shards_done_before} shards were already done"
    )
    write_json(
        args.json,
        {
            "plans": report.plans,
            "seconds": report.seconds,
            "plans_per_s": report.plans_per_s,
            "workers": args.workers,
            "skipped": report.skipped,
            "shards_done_before": report.shards_done_before,
        },
    )
    return 0


def _show(args: argparse.Namespace) -> int:
    from edge_explorer.errors import PlanError
    from edge_explorer.world.catalog import load_buildings_with_space
    from edge_explorer.world.render import save_plan_png

    loaded = load_buildings_with_space(args.plan)
    if len(loaded) != 1:
        raise PlanError(f"{args.plan!r} names {len(loaded)} plans; `plans show` draws one (use `plans sheet`)")
    raster, space = loaded[0]
    save_plan_png(raster, args.png, dropped=space.dropped)
    note = " (red: left out of N_M, no flight can reach or see it)" if space.dropped.any() else ""
    print(f"wrote {args.png}{note}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from edge_explorer.cli_support import write_json
    from edge_explorer.world.catalog import load_buildings_with_space
    from edge_explorer.world.grid import LOW_RES_M

    rows = []
    for raster, space in load_buildings_with_space(args.plans):
        low = raster.coarsened(LOW_RES_M)
        w, h = raster.grid.size_xy_m
        cell_m2 = raster.grid.resolution_m**2
        rows.append(
            {
                "name": raster.name,
                "grid_m": [round(w, 2), round(h, 2)],
                "interior_m2": float(raster.interior.sum() * cell_m2),
                "reachable_m2": float(space.reachable.sum() * cell_m2),
                "n_m": int(low.interior.sum()),
                "dropped_free_m2": round(space.dropped_free_m2, 3),
                "dropped_wall_m2": round(space.dropped_wall_m2, 3),
            }
        )
        dropped = ""
        if space.dropped.any():
            dropped = (
                f"  left out of N_M: {space.dropped_free_m2:.1f} m² floor, {space.dropped_wall_m2:.1f} m² wall "
                "no flight can reach or see"
            )
        print(
            f"{raster.name}: ok  grid {w:.1f}×{h:.1f} m  interior {rows[-1]['interior_m2']:.1f} m²  "
            f"reachable {rows[-1]['reachable_m2']:.1f} m²  N_M {rows[-1]['n_m']}{dropped}"
        )
    write_json(args.json, rows)
    return 0


def _sheet(args: argparse.Namespace) -> int:
    import numpy as np

    from edge_explorer.world.catalog import load_buildings, plan_to_raster
    from edge_explorer.world.dataset import generate_checked
    from edge_explorer.world.render import save_contact_sheet

    if args.plans:
        from edge_explorer.world.catalog import sheet_rasters

        rasters, titles = sheet_rasters(args.plans)
    else:
        rng = np.random.default_rng(args.seed)
        indices = sorted(rng.choice(45_000, size=args.count, replace=False).tolist())
        plans = [generate_checked(0, "train", int(k)) for k in indices]
        rasters = [plan_to_raster(p) for p in plans]
        titles = [f"{p.name} · {p.meta.get('style', '?')} · {p.meta.get('rooms', '?')} rooms" for p in plans]
    if args.extra:
        extra = load_buildings(args.extra)
        rasters += extra
        titles += [r.name for r in extra]
    save_contact_sheet(rasters, args.png, titles)
    print(f"wrote {args.png} ({len(rasters)} plans)")
    return 0
