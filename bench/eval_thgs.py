#!/usr/bin/env python
"""Evaluate THGS on a synthetic talking head: full model, without LEB, without SAAM.

    python bench/eval_thgs.py [--seconds 8] [--res 128] [--vertices 6000] [--iters 3000]
                              [--saam-from 0.4] [--out DIR] [--quick]

1. writes the synthetic talking data (``geoface talk synth``): a speech-like WAV drives the jaw and
   lips; the tracker poses hold only the head pose and the non-mouth expressions;
2. trains each variant on the first 80% of the frames (same seed and steps). The paper's stage
   starts (1.5K/15K/25K/50K) are scaled so that SAAM starts at ``--saam-from`` of the run;
3. on the held-out 20%: PSNR/SSIM over the person, PSNR of the mouth rectangle, lip sync (the
   correlation of the rendered mouth's openness with the audio loudness envelope, next to the
   real frames' own correlation) and the rendering FPS on CPU.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {"full": {}, "no_leb": {"use_leb": False}, "no_saam": {"use_saam": False}}


def main(argv=None) -> int:
    import torch

    from geoface.splat.thgs import PAPER_STAGES, THGSConfig, evaluate_thgs, load_thgs, train_thgs
    from geoface.splat.thgs_data import load_talking, make_synthetic_talking

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--vertices", type=int, default=6000)
    ap.add_argument("--iters", type=int, default=3000)
    ap.add_argument("--saam-from", type=float, default=0.1)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", default="/tmp/geoface_eval_thgs")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.quick:
        a.seconds, a.iters, a.vertices, a.res = 2.0, 30, 2000, 64
    out = Path(a.out)
    rows = []

    def emit(**row):
        print(json.dumps(row), flush=True)
        rows.append(row)

    scale = a.saam_from * a.iters / PAPER_STAGES[-1]
    emit(bench="eval_thgs", stage="config", seconds=a.seconds, res=a.res, vertices=a.vertices, iters=a.iters,
         stage_starts=[int(round(s * scale)) for s in PAPER_STAGES], threads=torch.get_num_threads())
    t = time.perf_counter()
    data_dir = out / "data"
    if not (data_dir / "poses.npz").is_file():
        make_synthetic_talking(data_dir, seconds=a.seconds, res=a.res, n_vertices=a.vertices, quiet=True)
    emit(stage="data", seconds=round(time.perf_counter() - t, 1))
    data = load_talking(data_dir)
    for name in a.variants.split(","):
        cfg = THGSConfig(iters=a.iters, stage_scale=scale, seed=0, **VARIANTS[name])
        info = train_thgs(data_dir, out / f"model_{name}", cfg, progress=False)
        h = info["history"]
        ev = evaluate_thgs(load_thgs(out / f"model_{name}"), data)
        emit(stage="heldout", variant=name, train_seconds=round(info["seconds"], 1), gaussians=info["n_gaussians"],
             loss_first=round(float(np.mean([r["loss"] for r in h[:20]])), 4),
             loss_last=round(float(np.mean([r["loss"] for r in h[-20:]])), 4), **{k: round(v, 4) for k, v in ev.items()})
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    from geoface.errors import GeofaceError
    try:
        sys.exit(main())
    except GeofaceError as e:
        print(f"eval_thgs: error: {e}", file=sys.stderr)
        sys.exit(2)
