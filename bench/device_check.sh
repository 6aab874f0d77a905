#!/usr/bin/env bash
# GPU checks for the neural add-ons, for a machine with CUDA (CI has none):
#   bash bench/device_check.sh [OUT_DIR]
# 1. geoface ddpm train/sample with --device cuda on a small synthetic dataset;
# 2. the splat tests that compare our rasterizer with gsplat (tests/splat/test_gsplat.py);
# 3. bench/bench_splat.py --device cuda (our torch path and gsplat side by side).
# Needs torch with CUDA, diffusers, accelerate, safetensors, trimesh and (for 2, 3) gsplat.
set -u
OUT=${1:-/tmp/geoface_device_check}
mkdir -p "$OUT"
PY=${PYTHON:-python3}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" GEOFACE_QUIET=1 PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"

echo "== ddpm on cuda"
$PY - "$OUT" <<'PY'
import sys, pathlib
sys.path.insert(0, "tests/learn")
from conftest import make_gimage_dataset
root = pathlib.Path(sys.argv[1]) / "ddpm_data"
root.mkdir(parents=True, exist_ok=True)
make_gimage_dataset(root, n_items=8, N=32)
PY
t0=$(date +%s%N)
$PY -m geoface ddpm train "$OUT/ddpm_data" -o "$OUT/ddpm_run" --res 32 --steps 200 --batch 8 \
    --text-encoder hash --device cuda --checkpoint-every 100 || echo "DDPM TRAIN FAILED"
t1=$(date +%s%N)
echo "ddpm train 200 steps (default UNet, 32², batch 8) on cuda: $(( (t1 - t0) / 1000000 )) ms"
$PY -m geoface ddpm sample "$OUT/ddpm_run" "a smiling female" -n 4 --steps 25 --device cuda \
    -o "$OUT/ddpm_samples" && ls "$OUT/ddpm_samples" | head || echo "DDPM SAMPLE FAILED"

echo "== gsplat comparison"
$PY -m pytest -q -p no:cacheprovider tests/splat/test_gsplat.py 2>&1 | tail -15

if [ -f bench/bench_splat.py ]; then
  echo "== bench_splat cuda"
  $PY bench/bench_splat.py --device cuda | tee "$OUT/bench_splat_cuda.jsonl"
fi
