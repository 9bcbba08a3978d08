#!/usr/bin/env bash
# Session 27: branch-credit labels -> two BC fine-tunes of the shipped policy -> val sweeps paired with round 1.
# Run from the repository root in .venv after branch_credit.py has written runs/s27/branch/train.
set -euo pipefail
export OMP_NUM_THREADS=1 PYTHONPATH=docs/policy
MARGIN=${MARGIN:-2.0}
python docs/policy/session27/labels.py runs/s27/branch/train --margin "$MARGIN" --out runs/s27/branch/demos
# C1: the branch labels alone, gently; C2: mixed with round 1's own self-imitation data (an anchor)
edge-explorer train goal-bc --train-demos runs/s27/branch/demos --val-demos runs/s24/si/val \
    --init models/policy/policy.safetensors --steps 200 --batch-size 32 --lr 1e-4 --threads 1 \
    --out runs/s27/bcC1 > runs/s27/bcC1.log 2>&1 &
edge-explorer train goal-bc --train-demos runs/s27/branch/demos,runs/s24/si/train --val-demos runs/s24/si/val \
    --init models/policy/policy.safetensors --steps 400 --batch-size 32 --lr 2e-4 --threads 1 \
    --out runs/s27/bcC2 > runs/s27/bcC2.log 2>&1 &
wait
python docs/policy/expert_sweep.py --name s27_C1 --first 40 --count 96 --planner drl \
    --policy runs/s27/bcC1/checkpoint.safetensors --workers 1 > runs/s27/swC1.log 2>&1 &
python docs/policy/expert_sweep.py --name s27_C2 --first 40 --count 96 --planner drl \
    --policy runs/s27/bcC2/checkpoint.safetensors --workers 1 > runs/s27/swC2.log 2>&1 &
wait
python docs/policy/expert_sweep.py --compare s27_C1 s24_si_last
python docs/policy/expert_sweep.py --compare s27_C2 s24_si_last
