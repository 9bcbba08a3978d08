#!/usr/bin/env bash
# The daemon's 20 acceptance flights: buildings A-D flown at once (5 flights each, one `edge-explorer run` per
# building), merged into one table. Usage, from the repository root after `make venv`:
#   bash scripts/acceptance_abcd.sh NAME COMPARE      e.g.  s38 docs/bench/policy_bundled.json
# writes runs/NAME/acc/ and docs/runtime/acceptance_NAME.{md,json,png}.
set -euo pipefail
SESSION=$1 COMPARE=$2
source .venv/bin/activate
mkdir -p "runs/$SESSION/acc"
for X in A B C D; do
  edge-explorer run --plans $X --runs 5 --compare "$COMPARE" --out "runs/$SESSION/acc/$X" --json "runs/$SESSION/acc/$X.json" \
    --markdown "runs/$SESSION/acc/$X.md" --plot "runs/$SESSION/acc/$X.png" > "runs/$SESSION/acc/$X.log" 2>&1 &
done
wait
python scripts/merge_acceptance.py --compare "$COMPARE" --out "docs/runtime/acceptance_$SESSION" \
  "runs/$SESSION/acc/A.json" "runs/$SESSION/acc/B.json" "runs/$SESSION/acc/C.json" "runs/$SESSION/acc/D.json"
