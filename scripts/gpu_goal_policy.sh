#!/usr/bin/env bash
# The goal policy's GPU stretch (issue #21), for a lent machine (`device`: one GPU, 16 cores), in one wall-time box:
#   1. the cores fly the predictive expert with PREDICTOR on train plans and record its labelled decisions
#      (`train goal-demos`, resumable shards of 10 plans) for DEMO_S seconds,
#   2. a short probe measures behaviour-cloning steps/s on this GPU (demonstrations on the device, bf16 autocast),
#   3. behaviour cloning (`train goal-bc --device cuda`) for BC_S seconds, its cosine schedule sized to end in them,
#   4. one DAgger round: DAGGER_POLICY (default the clone; `models/policy` = the shipped int8 policy) flies further
#      train plans while the expert labels every decision, for DAGGER_S seconds (0 = none: the box ends after cloning),
#   5. a fine-tune from INIT (default the clone) on the expert's and the DAgger decisions for the rest of the box,
#   6. the runs, the log and as many demonstration shards as $OUT takes back (45 MiB) are packed into $OUT.
# DEMO_S=0 skips steps 1-3: DAgger only, e.g. the shipped policy's own rollouts fine-tuning its own weights:
#   DEMO_S=0 DAGGER_S=300 DAGGER_POLICY=models/policy INIT=models/policy/policy.safetensors bash scripts/gpu_goal_policy.sh
# Needs VAL (made on the host with the same predictor: `train goal-demos --out data/goal_demos_h200/val --split val
# --count 40 --predictor runs/pred_h200`) and the predictor folder, both carried; it makes data/plans itself.
# EXTRA_DEMOS (comma-separated shard folders, carried) join every training stage: whole-floor demonstrations, which
# take minutes a floor and are made on the host beforehand (`train goal-demos --floors --split train --count N`).
# Wheels the machine lacks (ai-edge-litert for the int8 TFLite predictor, gymnasium) travel in .whl_goal/.
set -uo pipefail
BOX_S=${BOX_S:-570}
DEMO_S=${DEMO_S:-210}
BC_S=${BC_S:-120}
DAGGER_S=${DAGGER_S:-90}
PREDICTOR=${PREDICTOR:-runs/pred_h200_min}
VAL=${VAL:-data/goal_demos_h200/val}
DEMOS=${DEMOS:-data/goal_demos_h200}
RUNS=${RUNS:-runs/goal_gpu}
BATCH=${BATCH:-128}
DEVICE=${DEVICE:-cuda}
WORKERS=${WORKERS:-$(nproc)}
DAGGER_FIRST=${DAGGER_FIRST:-20000}  # DAgger flies plans the expert's round never reaches in one box
WHEELS=${WHEELS:-.whl_goal}
DAGGER_POLICY=${DAGGER_POLICY:-$RUNS/bc/best.safetensors}
INIT=${INIT:-$RUNS/bc/best.safetensors}
OUT=${OUT:-runs/gpu_out}
EXTRA_DEMOS=${EXTRA_DEMOS:-}
with_extra() { if [ -n "$EXTRA_DEMOS" ]; then echo "$1,$EXTRA_DEMOS"; else echo "$1"; fi; }
T0=$(date +%s)
left() { echo $((BOX_S - ($(date +%s) - T0))); }
mkdir -p "$OUT" "$RUNS"
exec > >(tee "$OUT/log.txt") 2>&1
if [ -d "$WHEELS" ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "$WHEELS"/*.whl
    export PYTHONPATH=/tmp/site:$PWD
else
    export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1
EE="python3 -m edge_explorer.cli"
nvidia-smi -L || true; nproc
python3 -c "import torch, gymnasium, ai_edge_litert, edge_explorer.learn.goal_demos; print('torch', torch.__version__)"

# Runs `$EE train goal-demos ARGS...` in its own process group for at most $1 seconds, then ends it (finished shards
# carry their marker; a shard cut off is ignored by the loader and redone by a resume).
demos_for() {
    local seconds=$1; shift
    setsid $EE train goal-demos "$@" &
    local pid=$!
    for _ in $(seq "$seconds"); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
    kill -TERM -- -"$pid" 2>/dev/null; wait "$pid" 2>/dev/null
}
# Steps that fill $1 seconds at the probe's rate (90 %: validations and checkpoints take the rest).
steps_for() { python3 -c "print(max(100, int($RATE * $1 * 0.9) // 50 * 50))"; }

echo "== 0. plans $(date -u +%T)"  # deterministic: the same 50,000 plans as on the host
[ -f data/plans/manifest.json ] || $EE plans generate --count 50000 --seed 0 --out data/plans --workers "$WORKERS"

if [ "$DEMO_S" -gt 0 ]; then
echo "== 1. expert demonstrations ($DEMO_S s, $WORKERS workers) $(date -u +%T)"
demos_for "$DEMO_S" --out "$DEMOS/train" --split train --count 20000 --predictor "$PREDICTOR" --workers "$WORKERS"
echo "finished expert shards: $(ls "$DEMOS"/train/*.json | wc -l)"
fi

echo "== 2. probe $(date -u +%T)"
rm -rf "$RUNS/probe"
$EE train goal-bc --train-demos "$VAL" --val-demos "$VAL" --steps 100000 --batch-size "$BATCH" --device "$DEVICE" \
    --max-minutes 0.25 --out "$RUNS/probe"
RATE=$(python3 -c "import json; s = json.load(open('$RUNS/probe/state.json')); print(s['step'] / s['wall_s'])")
echo "steps/s: $RATE"

if [ "$DEMO_S" -gt 0 ]; then
echo "== 3. behaviour cloning ($BC_S s) $(date -u +%T)"
rm -rf "$RUNS/bc"
$EE train goal-bc --train-demos "$(with_extra "$DEMOS/train")" --val-demos "$VAL" --steps "$(steps_for "$BC_S")" \
    --batch-size "$BATCH" --device "$DEVICE" --max-minutes "$(python3 -c "print($BC_S / 60)")" --out "$RUNS/bc"
fi

if [ "$DAGGER_S" -gt 0 ] && [ -e "$DAGGER_POLICY" ] && [ -f "$INIT" ] && [ "$(left)" -gt $((DAGGER_S + 90)) ]; then
    echo "== 4. DAgger round ($DAGGER_S s) $(date -u +%T)"
    demos_for "$DAGGER_S" --out "$DEMOS/dagger1" --split train --first "$DAGGER_FIRST" --count 20000 \
        --predictor "$PREDICTOR" --policy "$DAGGER_POLICY" --workers "$WORKERS"
    echo "finished DAgger shards: $(ls "$DEMOS"/dagger1/*.json | wc -l)"
    FT_S=$(( $(left) - 60 ))
    echo "== 5. fine-tune on expert + DAgger ($FT_S s) $(date -u +%T)"
    rm -rf "$RUNS/dagger1"
    TRAIN=$DEMOS/dagger1; [ -d "$DEMOS/train" ] && TRAIN=$DEMOS/train,$TRAIN
    $EE train goal-bc --train-demos "$(with_extra "$TRAIN")" --val-demos "$VAL" \
        --init "$INIT" --lr 3e-4 --steps "$(steps_for "$FT_S")" --batch-size "$BATCH" \
        --device "$DEVICE" --max-minutes "$(python3 -c "print($FT_S / 60)")" --out "$RUNS/dagger1"
fi

echo "== 6. pack $(date -u +%T)"
nvidia-smi --query-gpu=name,memory.used --format=csv || true
tar czf "$OUT/runs.tar.gz" --exclude='*optimizer.safetensors' "$RUNS"
# demonstration shards, DAgger's first, up to 45 MiB (the rest stays on the machine)
python3 - "$DEMOS" > /tmp/shards.txt <<'PY'
import pathlib, sys
root, total = pathlib.Path(sys.argv[1]), 0
for sub in ("dagger1", "train"):
    for npz in sorted((root / sub).glob("shard-*.npz")):
        marker = npz.with_suffix(".json")
        if marker.exists() and total + npz.stat().st_size < 45 * 2**20:
            total += npz.stat().st_size
            print(npz); print(marker)
PY
tar cf - -T /tmp/shards.txt | split -b 15M - "$OUT/demo_shards.tar."
ls -la "$OUT"
