#!/usr/bin/env bash
# Self-imitation round 2 on a lent machine's 16 cores (issue #21, session 25): the round-1 policy flies train plans
# greedily and sampled (docs/policy/session24/self_imitation.py), a demo shard per block of 16 plans, until the box
# ends; the GPU is not used (flights are CPU work). Carry .whl_goal (cp312 wheels the machine lacks: ai-edge-litert,
# gymnasium and its small deps, safetensors) and runs/plans_carry (train plan shards 0-11, plans 0-5999); leave
# docs/predictor out of the tree for the call (`git rm -r -q --cached docs/predictor`, then `git reset -q`).
#   BOX_S=540 bash docs/policy/session25/lease_si.sh     # $OUT/si.tar.gz: val/ and train/ shards + summaries
set -uo pipefail
BOX_S=${BOX_S:-540}
FIRST=${FIRST:-3340}
POLICY=${POLICY:-docs/policy/session24/si_round1.safetensors}
T0=$(date +%s)
left() { echo $((BOX_S - ($(date +%s) - T0))); }
OUT=${OUT:-runs/gpu_out}
mkdir -p "$OUT"
exec > >(tee "$OUT/log.txt") 2>&1
python3 -m pip install -q --upgrade --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl_goal/*.whl
CORES=$(nproc)  # before OMP_NUM_THREADS: GNU nproc honours it (session 25's lease flew on 1 worker that way)
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
echo "$CORES cores"; python3 -c "import torch, gymnasium, ai_edge_litert, safetensors, numpy; print(torch.__version__, numpy.__version__)"
SI="python3 docs/policy/session24/self_imitation.py --samples 4 --temperature 0.5 --policy $POLICY \
    --plans runs/plans_carry --workers $CORES"
# Runs $SI ARGS... in its own process group until the box has $1 seconds left, then ends it (finished blocks stay).
until_left() {
    local keep=$1; shift
    setsid $SI "$@" &
    local pid=$!
    while kill -0 "$pid" 2>/dev/null && [ "$(left)" -gt "$keep" ]; do sleep 1; done
    kill -TERM -- -"$pid" 2>/dev/null; wait "$pid" 2>/dev/null
}
echo "== val $(date -u +%T)"
until_left 200 --first 3220 --count 20 --block 4 --out runs/si2/val
echo "== train $(date -u +%T), $(left) s left"
until_left 25 --first "$FIRST" --count 2000 --block 16 --out runs/si2/train
echo "== pack $(date -u +%T)"
ls runs/si2/train | tail -3
tar czf "$OUT/si.tar.gz" runs/si2
ls -la "$OUT"
