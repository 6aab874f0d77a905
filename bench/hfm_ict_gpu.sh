#!/usr/bin/env bash
# HFM-GS on held-out ICT people (bench/eval_hfm_ict.py) on a CUDA machine, in priority order so that
# what finishes within the time limit is the most useful part:
#   bash bench/hfm_ict_gpu.sh DATA_DIR OUT_DIR [SECONDS] [JOBS]
# DATA_DIR: the captures of `python bench/eval_hfm_ict.py data` (DATA_DIR/val_10, test_11, ...).
# 1. a 200-step smoke run (warm-up, density control, averaging, scoring) on cuda; stops on an error;
# 2. test people × model seed 0: oracle / Full / the two ablations; validation × seeds 0, 1: Full and
#    each of the paper's elements (the choice); test × seed 1; validation ablations; test × the elements.
# Results: OUT_DIR/results.jsonl (one JSON line per score), OUT_DIR/smoke.jsonl.
set -u
DATA=$1; OUT=$2; LIMIT=${3:-480}; JOBS=${4:-14}
PY=${PYTHON:-python3}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" GEOFACE_QUIET=1 PYTHONUNBUFFERED=1
mkdir -p "$OUT"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
MAIN=oracle,full,no_gaussian_feature_mapping,no_global_pose
PAPER=map_theta,gm_xsr,pm_per_component,split_margin
t0=$(date +%s)
$PY bench/eval_hfm_ict.py run --out /tmp/hfm_smoke --data "$DATA" --group val/0/full --iters 200 --device cuda \
    | tee "$OUT/smoke.jsonl"
echo "smoke: $(( $(date +%s) - t0 )) s"
if grep -q '"error"' "$OUT/smoke.jsonl" || ! grep -q '"score"' "$OUT/smoke.jsonl"; then
  echo "SMOKE FAILED"; exit 1
fi
timeout "$LIMIT" $PY bench/eval_hfm_ict.py run --out "$OUT" --models /tmp/hfm_models --data "$DATA" --jobs "$JOBS" \
    --device cuda --iters 1500 --group "test/0/$MAIN" --group "val/0,1/full,$PAPER" --group "test/1/$MAIN" \
    --group "val/0,1/oracle,no_gaussian_feature_mapping,no_global_pose" --group "test/0,1/$PAPER" > "$OUT/run.log" 2>&1
echo "exit $? after $(( $(date +%s) - t0 )) s; $(grep -c '"score"' "$OUT/results.jsonl" 2>/dev/null) scores"
grep '"error"' "$OUT/results.jsonl" | head -3
