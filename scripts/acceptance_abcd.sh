#!/usr/bin/env bash
# The daemon's 20 acceptance flights: buildings A-D flown at once (5 flights each, one `edge-explorer run` per
# building), merged into one table. Usage, from the repository root after `make venv`:
#   bash docs/runtime/acceptance_abcd.sh SESSION COMPARE      e.g.  s28 docs/bench/policy_bundled.json
# writes runs/SESSION/acc/ and docs/runtime/acceptance_SESSION.{md,json,png}. (Session 26 flew it as s26 against
# runs/s25/bundled.json, the bench that docs/bench/policy_bundled.json keeps.)
set -euo pipefail
SESSION=$1 COMPARE=$2
source .venv/bin/activate
mkdir -p "runs/$SESSION/acc"
for X in A B C D; do
  edge-explorer run --plans $X --runs 5 --compare "$COMPARE" --out "runs/$SESSION/acc/$X" --json "runs/$SESSION/acc/$X.json" \
    --markdown "runs/$SESSION/acc/$X.md" --plot "runs/$SESSION/acc/$X.png" > "runs/$SESSION/acc/$X.log" 2>&1 &
done
wait
python docs/runtime/merge_acceptance.py --compare "$COMPARE" --out "docs/runtime/acceptance_$SESSION" \
  "runs/$SESSION/acc/A.json" "runs/$SESSION/acc/B.json" "runs/$SESSION/acc/C.json" "runs/$SESSION/acc/D.json"
