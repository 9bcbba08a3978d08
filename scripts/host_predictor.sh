#!/usr/bin/env bash
# Issue #17's long predictor run on the host's CPU, spread over sessions (docs/predictor/at_scale.md, session 29).
# Each call: (1) the 50,000 plans if missing, (2) the 300 val plans of predictor samples if missing, (3) the first
# SHARDS train shards (50 plans each) recorded into data/predictor3 if missing (resumable), (4) those shards
# hard-linked into data/p3host/train, a fixed snapshot (a resumed run must see the same data), (5) training started
# or resumed for MINUTES of wall time with bfloat16 autocast (a CPU with AVX512-BF16/AMX; PRECISION=fp32 elsewhere).
# Run it niced in the background at the start of a session:
#   nohup nice -n 5 bash scripts/host_predictor.sh > runs/host_predictor.log 2>&1 &
# On a lent GPU the same run can go on (same config, batches and schedule; `--resume` loads the checkpoint onto
# --device; not yet tried on a GPU): carry
# data/p3host (21 MB), data/predictor3/val and the run folder (26 MB: weights + optimizer), with docs/ and models/
# left out of the index for that call as scripts/gpu_predictor.sh's header shows, then
#   python3 -m edge_explorer.cli train predictor --config edge_explorer/learn/configs/predictor_host_wide.toml \
#       --out runs/predictor_host_wide --resume --device cuda --loader-workers 12 --max-minutes 8 && cp -r runs/predictor_host_wide $OUT/
# and copy the folder back over runs/predictor_host_wide here; the next host call resumes from it.
set -euo pipefail
SHARDS=${SHARDS:-250}
MINUTES=${MINUTES:-150}
WORKERS=${WORKERS:-$(nproc)}
PRECISION=${PRECISION:-bf16}
CONFIG=${CONFIG:-edge_explorer/learn/configs/predictor_host_wide.toml}
RUN=${RUN:-runs/predictor_host_wide}
EE=${EE:-.venv/bin/edge-explorer}
DATA="--noise-free-fraction 0.3 --workers $WORKERS"  # the recording settings of every predictor3 shard

[ -f data/plans/manifest.json ] && [ "$(ls data/plans/train/*.jsonl.gz | wc -l)" -ge 90 ] ||
    $EE plans generate --count 50000 --seed 0 --out data/plans --workers "$WORKERS"
$EE train predictor-data --out data/predictor3 --train-plans 0 --val-plans 300 $DATA
$EE train predictor-data --out data/predictor3 --train-plans $((SHARDS * 50)) --val-plans 0 $DATA
mkdir -p data/p3host/train
for i in $(seq 0 $((SHARDS - 1))); do
    name=$(printf 'shard-%05d' "$i")
    for ext in npz json; do
        [ -e "data/p3host/train/$name.$ext" ] || ln "data/predictor3/train/$name.$ext" "data/p3host/train/$name.$ext"
    done
done
RESUME=""
[ -f "$RUN/state.json" ] && RESUME="--resume"
$EE train predictor --config "$CONFIG" --out "$RUN" $RESUME --precision "$PRECISION" --max-minutes "$MINUTES"
