source .venv/bin/activate
mkdir -p runs/s26/acc
for X in A B C D; do
  edge-explorer run --plans $X --runs 5 --compare runs/s25/bundled.json --out runs/s26/acc/$X --json runs/s26/acc/$X.json --markdown runs/s26/acc/$X.md --plot runs/s26/acc/$X.png > runs/s26/acc/$X.log 2>&1 &
done
wait
python docs/runtime/merge_acceptance.py --compare runs/s25/bundled.json --out docs/runtime/acceptance_s26 runs/s26/acc/A.json runs/s26/acc/B.json runs/s26/acc/C.json runs/s26/acc/D.json
