source .venv/bin/activate
mkdir -p runs/s28/acc
for X in A B C D; do
  edge-explorer run --plans $X --runs 5 --compare docs/bench/policy_bundled.json --out runs/s28/acc/$X --json runs/s28/acc/$X.json --markdown runs/s28/acc/$X.md --plot runs/s28/acc/$X.png > runs/s28/acc/$X.log 2>&1 &
done
wait
python docs/runtime/merge_acceptance.py --compare docs/bench/policy_bundled.json --out docs/runtime/acceptance_s28 runs/s28/acc/A.json runs/s28/acc/B.json runs/s28/acc/C.json runs/s28/acc/D.json
