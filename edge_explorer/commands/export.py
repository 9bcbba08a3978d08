"""``edge-explorer export``: run quantization recipes (``quantize/*.toml``) and print the format table.

Exit codes: 0 every gate passed (artifacts and card installed), 1 a gate failed (nothing installed, the previous
artifacts untouched), 2 bad input (recipe, checkpoint, missing converter environment).

``--all`` skips, with one line each, the recipes whose checkpoint has not been trained yet (e.g. the goal policy
before its training has produced ``models/policy/policy.safetensors``); ``--recipe`` names one recipe and
a missing checkpoint is an error.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from edge_explorer.errors import EdgeExplorerError

RECIPE_DIR = Path(__file__).resolve().parents[2] / "quantize"


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export",
        help="torch → ONNX fp32 → int8 ONNX / int8 TFLite, with accuracy gates and model cards",
        description="Export and quantize the models of one recipe (or all of quantize/*.toml), check the "
        "accuracy gates on held-back simulator observations, and update models/<name>/card.json.",
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--recipe", type=Path, help="a recipe TOML, e.g. quantize/predictor.toml")
    which.add_argument("--all", action="store_true", help=f"every recipe in {RECIPE_DIR}")
    parser.add_argument("--out", type=Path, default=Path("models"), help="models folder (default: models/)")
    parser.add_argument("--json", type=Path, help="write the figures (format table, gates, card) as JSON")
    parser.set_defaults(func=export_cli)


def export_cli(args: argparse.Namespace) -> int:
    from edge_explorer.cli_support import write_json
    from edge_explorer.export.pipeline import run_export
    from edge_explorer.export.recipe import check_inputs_exist, load_recipe

    paths = sorted(RECIPE_DIR.glob("*.toml")) if args.all else [args.recipe]
    if not paths:
        raise EdgeExplorerError(f"no recipes in {RECIPE_DIR}")
    recipes = [load_recipe(p) for p in paths]
    if args.all:
        for recipe in recipes:
            if not recipe.checkpoint.is_file():
                print(f"== {recipe.name}: skipped, checkpoint {recipe.checkpoint} does not exist (not trained yet)")
        recipes = [r for r in recipes if r.checkpoint.is_file()]
        if not recipes:
            raise EdgeExplorerError(f"no recipe in {RECIPE_DIR} has its checkpoint; train the models first")
    for recipe in recipes:  # every recipe and checkpoint is checked before the first long run
        check_inputs_exist(recipe)
    reports = []
    for recipe in recipes:
        print(f"== {recipe.name}: {recipe.path}")
        report = run_export(recipe, args.out)
        reports.append(report)
        print(report.table())
        if report.passed:
            print(f"installed in {report.out_dir} (card.json updated)")
        else:
            print(f"gate failed, nothing installed ({report.out_dir} untouched): {'; '.join(report.failures())}")
    write_json(args.json, [r.to_json() for r in reports])
    return 0 if all(r.passed for r in reports) else 1
