#!/usr/bin/env bash
# The map predictor's GPU stretch (issue #17), for a lent machine (`device`: one GPU, 16 cores), in one wall-time box:
#   1. the cores record predictor samples (`train predictor-data`, resumable shards) for DATA_S seconds,
#   2. a short probe measures training steps/s on this GPU with DataLoader workers and bfloat16 autocast (skipped when
#      RATE gives the steps/s already measured on this kind of machine: an H200 ran 32-38),
#   3. the U-Net trains for the rest of the box with total_steps set from that rate (the cosine schedule ends in it),
#   4. the run folder, the train shards recorded in this box and the log are packed into $OUT (at most 16 MiB a file).
# DATA_S=0 skips step 1; TRAIN=0 ends the box after it. A call carries at most 64 MiB: the tracked tree (about 40 MB,
# most of it docs/ and models/), the OR-Tools wheel (.whl, 30 MB, needed to record) and the samples (data/predictor3,
# 15 MB) do not fit together. Session 18 ran the whole box in ONE call by leaving docs/ and models/ out of the tree
# for that call only (the index alone changes; no file is touched) and carrying the init checkpoint's folder:
#   cp .git/info/exclude /tmp/exclude.bak && git rm -r -q --cached docs models && printf '/docs/\n/models/\n' >> .git/info/exclude
#   run: carry .whl, data/predictor3, docs/predictor/gpu_h100/stretchN (the config's init_weights folder);
#        BOX_S=540 DATA_S=170 RATE=33 CONFIG=edge_explorer/learn/configs/predictor_gpu_stretchN.toml bash scripts/gpu_predictor.sh
#   then at once: git reset -q && cp /tmp/exclude.bak .git/info/exclude
#   and unpack $OUT/run.tar.gz (the run) and $OUT/train_shards.tar.* (in data/predictor3/train) on the host.
# Sessions 13-16 split it in two calls instead (record with CARRIED=runs/carry_p3 TRAIN=0, a markers-only carry made
# by `mkdir -p runs/carry_p3/train && cp -r data/predictor3/{manifest.json,val} runs/carry_p3/ &&
# cp data/predictor3/train/*.json runs/carry_p3/train/`; then train with DATA_S=0 on the warm machine within 30 s),
# which spends a second call's transfers and more of the lease's 15 minutes.
# The host records faster than a short lease box (session 18: 2 cores ~3 plans/s; the lease 9.4 plans/s over its
# 170 s with start-up, on 16 cores), and it has hours: from session 18 on the host records between leases
# (`train predictor-data --out data/predictor3 --train-plans 45000 --val-plans 300 --workers 2
# --noise-free-fraction 0.3`, resumable) and a lease trains only: DATA_S=0, no .whl, carrying data/predictor3
# (~1.6 MiB per 1,000 plans). All 45,000 plans (~75 MiB) take two calls on the same warm machine; data/predictor3
# is not a carried path of the second call, so what the first call copied into it stays:
#   mkdir -p runs/carry_p3a/train runs/carry_p3b/train && cp -r data/predictor3/{manifest.json,val} runs/carry_p3a/
#   cp -l data/predictor3/train/shard-00[0-3]* data/predictor3/train/shard-004[0-4]* runs/carry_p3a/train/
#   cp -l data/predictor3/train/shard-004[5-9]* data/predictor3/train/shard-00[5-9]* runs/carry_p3b/train/
#   call 1, carry runs/carry_p3a: mkdir -p data/predictor3 && cp -r runs/carry_p3a/. data/predictor3/
#   call 2, carry runs/carry_p3b and the init folder: CARRIED=runs/carry_p3b DATA_S=0 RATE=33 ... bash THIS
# Session 20: a session can start on a new machine without the previous one's ignored folders (data/, runs/); the
# 42,450 plans recorded into data/predictor3 by session 19 were lost that way. Check `ls data/predictor3/train | wc -l`
# before planning a lease around them; the host re-records ~1.6 plans/s on its two cores.
# Needs data/predictor3/val (made on the host: `train predictor-data --out data/predictor3 --train-plans 0
# --val-plans 300 --noise-free-fraction 0.3`, the same samples the machine would make); it makes data/plans itself.
# Wheels the machine lacks (OR-Tools for the FUEL-style explorer) travel in .whl/.
set -uo pipefail
BOX_S=${BOX_S:-540}
DATA_S=${DATA_S:-300}
TRAIN=${TRAIN:-1}
CARRIED=${CARRIED:-}  # a folder copied into data/predictor3 first (the markers-only carry of a recording call)
DEVICE=${DEVICE:-cuda}
PROBE_STEPS=${PROBE_STEPS:-150}
LOADERS=${LOADERS:-12}
CONFIG=${CONFIG:-edge_explorer/learn/configs/predictor_gpu.toml}  # its total_steps / val_every_steps lines are rewritten
RUN=${RUN:-runs/predictor_gpu}
OUT=${OUT:-runs/gpu_out}
T0=$(date +%s)
left() { echo $((BOX_S - ($(date +%s) - T0))); }
mkdir -p "$OUT"
exec > >(tee "$OUT/log.txt") 2>&1
if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    export PYTHONPATH=/tmp/site:$PWD
else
    export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1
EE="python3 -m edge_explorer.cli"
nvidia-smi -L || true; nproc; python3 -c "import torch, numpy, numba; print(torch.__version__, numpy.__version__, numba.__version__)"

# deterministic: the same 50,000 plans as on the host, in ~25 s on 16 cores; only recording needs them (the sample
# shards hold their plans' truth)
if [ "$DATA_S" -gt 0 ] && [ ! -f data/plans/manifest.json ]; then
    echo "== 0. plans $(date -u +%T)"
    $EE plans generate --count 50000 --seed 0 --out data/plans --workers "$(nproc)"
fi
touch /tmp/box_start
if [ -n "$CARRIED" ]; then mkdir -p data/predictor3 && cp -r "$CARRIED"/. data/predictor3/; fi
if [ "$DATA_S" -gt 0 ]; then
echo "== 1. samples ($DATA_S s, $(nproc) workers) $(date -u +%T)"
# its own process group, so the box ends the pool's workers too (finished shards have their marker; the rest is
# ignored by the loader and redone by a resume)
setsid $EE train predictor-data --out data/predictor3 --train-plans 45000 --val-plans 300 \
    --workers "$(nproc)" --noise-free-fraction 0.3 &
DATA_PID=$!
for _ in $(seq "$DATA_S"); do kill -0 "$DATA_PID" 2>/dev/null || break; sleep 1; done
kill -TERM -- -"$DATA_PID" 2>/dev/null; wait "$DATA_PID" 2>/dev/null
echo "finished train shards: $(ls data/predictor3/train/*.json | wc -l)"
fi

if [ "$TRAIN" = 1 ]; then
if [ -n "${RATE:-}" ]; then echo "== 2. probe skipped: RATE=$RATE steps/s given"; else
echo "== 2. probe $(date -u +%T)"
python3 - "$CONFIG" <<'PY'
import pathlib, sys
src = pathlib.Path(sys.argv[1]).read_text()
probe = src.replace("total_steps = 6000", "total_steps = 100000").replace("val_every_steps = 1000", "val_every_steps = 100000")
pathlib.Path("/tmp/probe.toml").write_text(probe)
PY
rm -rf runs/probe
$EE train predictor --config /tmp/probe.toml --out runs/probe --device "$DEVICE" --loader-workers "$LOADERS" --max-steps "$PROBE_STEPS"
# steps/s after the first logged step (the loader's start-up before it made the first lease's estimate 20 % low)
RATE=$(python3 -c "
import csv, json
rows = list(csv.DictReader(open('runs/probe/train_log.csv')))
if len(rows) >= 2:
    print((int(rows[-1]['step']) - int(rows[0]['step'])) / (float(rows[-1]['wall_s']) - float(rows[0]['wall_s'])))
else:
    s = json.load(open('runs/probe/state.json')); print(s['step'] / s['wall_s'])")
fi  # probe
echo "steps/s: $RATE"

echo "== 3. train $(date -u +%T), $(left) s left"
python3 - "$RATE" "$(left)" "$CONFIG" <<'PY'
import pathlib, sys
rate, left_s, config = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
budget_s = left_s - 75  # start-up, 8 validations, checkpoints, packing
total = max(500, int(rate * budget_s * 0.9) // 100 * 100)
src = pathlib.Path(config).read_text()
cfg = src.replace("total_steps = 6000", f"total_steps = {total}").replace(
    "val_every_steps = 1000", f"val_every_steps = {max(100, total // 8)}")
pathlib.Path("/tmp/gpu.toml").write_text(cfg)
print(f"total_steps {total} for {budget_s:.0f} s at {rate:.1f} steps/s")
PY
rm -rf "$RUN"
$EE train predictor --config /tmp/gpu.toml --out "$RUN" --device "$DEVICE" --loader-workers "$LOADERS" \
    --max-minutes "$(python3 -c "print(max(0.2, ($(left) - 40) / 60))")"

fi  # TRAIN

echo "== 4. pack $(date -u +%T)"
nvidia-smi --query-gpu=name,memory.used --format=csv || true
[ "$TRAIN" = 1 ] && tar czf "$OUT/run.tar.gz" "$RUN" $(ls runs/probe/state.json runs/probe/train_log.csv 2>/dev/null)
# only the shards this box finished (an .npz with its .json marker), to be unpacked in data/predictor3/train
NEW=$(cd data/predictor3/train && for f in $(find . -name 'shard-*.npz' -newer /tmp/box_start | sort); do
    [ -f "${f%.npz}.json" ] && echo "$f ${f%.npz}.json"; done)
[ -n "$NEW" ] && (cd data/predictor3/train && tar cf - $NEW) | split -b 15M - "$OUT/train_shards.tar."
ls -la "$OUT"
