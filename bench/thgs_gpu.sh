#!/usr/bin/env bash
# THGS on a CUDA machine: training on the GPU (smoke run, then the ICT captures), the per-frame pose
# corrections' rate schedule on the validation person and the test person, all runs at once:
#   bash bench/thgs_gpu.sh DATA_ROOT OUT_DIR [SECONDS]
# DATA_ROOT/val/data, DATA_ROOT/test/data: captures of `python bench/eval_thgs.py --head ict --seconds 12`
# (validation: --data-seed 1; test: --data-seed 0).  Each run also trains on the capture with its tracking
# perturbed by 3 deg / 5 mm (made here from the capture).  Results: OUT_DIR/<split>_<setting>.jsonl.
set -u
DATA=$1; OUT=$2; LIMIT=${3:-480}
PY=${PYTHON:-python3}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" GEOFACE_QUIET=1 PYTHONUNBUFFERED=1
mkdir -p "$OUT"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
t0=$(date +%s)
$PY bench/eval_thgs.py --quick --device cuda --variants full --out /tmp/thgs_smoke > "$OUT/smoke.jsonl" 2>&1
echo "smoke: $(( $(date +%s) - t0 )) s"
if ! grep -q '"heldout"' "$OUT/smoke.jsonl"; then tail -5 "$OUT/smoke.jsonl"; echo "SMOKE FAILED"; exit 1; fi
run() {  # split data_seed setting [eval_thgs options]
  local split=$1 dseed=$2 name=$3; shift 3
  local d=/tmp/thgs_runs/${split}_$name
  mkdir -p "$d" && ln -sfn "$(realpath "$DATA/$split/data")" "$d/data"
  timeout "$LIMIT" $PY bench/eval_thgs.py --head ict --seconds 12 --iters 3000 --saam-from 0.1 --threads 1 \
      --variants full --perturb 3,5 --data-seed "$dseed" --device cuda --out "$d" "$@" > "$OUT/${split}_$name.jsonl" 2>&1
}
for split in val:1 test:0; do
  s=${split%%:*}; k=${split##*:}
  run "$s" "$k" default &
  run "$s" "$k" lr5e-3_d10 --pose-decay 10 &
  run "$s" "$k" lr1e-2_d10 --lr-pose 0.01 --pose-decay 10 &
  run "$s" "$k" lr2e-2_d10 --lr-pose 0.02 --pose-decay 10 &
done
wait
echo "all: $(( $(date +%s) - t0 )) s"
grep -h '"heldout"' "$OUT"/*_*.jsonl | cut -c1-300
