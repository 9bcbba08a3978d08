"""Merge acceptance benches flown as separate processes into one table, JSON and figure.

The daemon's acceptance flights are real-time and use ~9 % of a core each, so the four buildings can fly at once,
one ``edge-explorer run --plans X --runs 5 --compare BENCH --json runs/acc/X.json`` per building; this script joins
their flights with the same summary, Markdown and plot as a single ``run --plans A,B,C,D`` would write::

    python scripts/merge_acceptance.py --compare docs/bench/policy_bundled.json --out docs/runtime/acceptance_NAME \
        runs/s10/acc/A.json runs/s10/acc/B.json runs/s10/acc/C.json runs/s10/acc/D.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from edge_explorer.runtime.acceptance import load_reference, markdown_report, plot_acceptance, summarize


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("parts", nargs="+", type=Path, help="the per-building `run --plans X --json` files")
    parser.add_argument("--compare", type=Path, required=True, help="the bench explore JSON the flights compare with")
    parser.add_argument("--out", type=Path, required=True, help="writes OUT.json, OUT.md and OUT.png")
    args = parser.parse_args()
    docs = [json.loads(p.read_text()) for p in args.parts]
    flights = sorted((f for d in docs for f in d["flights"]), key=lambda f: (f["run"], f["plan"]))
    table = summarize(flights, load_reference(args.compare))
    doc = {
        "command": " && ".join(d["command"] for d in docs) + " (merged by scripts/merge_acceptance.py)",
        "plans": ",".join(d["plans"] for d in docs),
        "runs_per_plan": docs[0]["runs_per_plan"],
        "time_limit_s": docs[0]["time_limit_s"],
        "compared_with": str(args.compare),
        "summary": table,
        "flights": flights,
    }
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(markdown_report(doc))
    plot_acceptance(args.out.with_suffix(".png"), flights, table)


if __name__ == "__main__":
    main()
