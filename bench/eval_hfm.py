#!/usr/bin/env python
"""Evaluate HFM-GS on synthetic HMD videos: Full and each ablation, plus FPS.

    python bench/eval_hfm.py [--frames 200] [--res 128] [--vertices 8000] [--iters 1500]
                             [--variants full,no_global_pose,...] [--out DIR] [--quick]

1. writes a synthetic sequence (``geoface hmd synth``): the first 80% is the registration video,
   the last 20% the held-out usage video with a rendered headset (and its unoccluded frames);
2. trains Full and each ablation on the registration video (same seed, same steps);
3. on the usage video: PSNR and SSIM of the rendered face against the unoccluded frames, over the
   whole face (foreground) and over the region the headset hides;
4. FPS of the per-frame path (crop → E_img → deformation/mapping → rasterize) at ``--res`` and at
   twice that (the same model rendered by a camera with doubled resolution), CPU.

Prints one JSON object per line; ``--out/results.json`` collects them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    import torch

    from geoface.camera import Camera
    from geoface.hfm import ABLATIONS, HFMConfig, evaluate_hmd, hmd_metrics, load_hfm, remove_hmd, train_hfm
    from geoface.hfm.data import load_video, make_synthetic_hmd

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--vertices", type=int, default=8000)
    ap.add_argument("--iters", type=int, default=1500)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--variants", default=",".join(ABLATIONS))
    ap.add_argument("--seed", type=int, default=0, help="model seed (initialisation, key sampling); the data stay the same")
    ap.add_argument("--reg-frames", type=int, default=None,
                    help="register from only the first K frames of the registration video (a short registration); "
                         "the held-out usage video stays the same")
    ap.add_argument("--data-seed", type=int, default=0, help="seed of the synthetic head and its sequence")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override an HFMConfig field for every variant (JSON value), e.g. --set detach_lower=true")
    ap.add_argument("--score-every", type=int, default=0, metavar="K",
                    help="once the weight average has started, score the held-out video every K steps with the "
                         "last step's weights and with the average (one 'trace' line each time)")
    ap.add_argument("--out", default="/tmp/geoface_eval_hfm")
    ap.add_argument("--quick", action="store_true", help="smoke: 20 frames, 2 variants, 30 steps")
    a = ap.parse_args(argv)
    if a.quick:
        a.frames, a.iters, a.vertices, a.variants = 20, 30, 3000, "full,no_gaussian_feature_mapping"
    if a.threads:
        torch.set_num_threads(a.threads)
    out = Path(a.out)
    rows = []
    overrides = {}
    for kv in a.set:
        k, _, v = kv.partition("=")
        try:
            overrides[k] = json.loads(v)
        except ValueError:
            overrides[k] = v  # a plain string

    def emit(**row):
        print(json.dumps(row), flush=True)
        rows.append(row)

    emit(bench="eval_hfm", stage="config", frames=a.frames, res=a.res, vertices=a.vertices, iters=a.iters,
         threads=torch.get_num_threads(), seed=a.seed, reg_frames=a.reg_frames, data_seed=a.data_seed, overrides=overrides)
    t = time.perf_counter()
    if not (out / "usage" / "gt").is_dir():
        make_synthetic_hmd(out, frames=a.frames, res=a.res, n_vertices=a.vertices, seed=a.data_seed, quiet=True)
    emit(stage="data", seconds=round(time.perf_counter() - t, 1))
    usage = load_video(out / "usage")
    for name in a.variants.split(","):
        cfg = replace(HFMConfig.from_dict({"iters": a.iters, "seed": a.seed, **overrides}), **ABLATIONS[name])
        tag = name + (f"_reg{a.reg_frames}" if a.reg_frames else "") + (f"_s{a.seed}" if a.seed else "") + \
            "".join(f"_{k}{v}" for k, v in overrides.items())
        def trace(step, model, average, name=name):
            if not a.score_every or average is None or (step + 1) % a.score_every:
                return
            row = {}
            model.eval()
            for which in ("last", "average"):
                with average.applied(model) if which == "average" else nullcontext():
                    ev = hmd_metrics(remove_hmd(model, usage)[0], usage)
                row.update({f"{k}_{which}": round(ev[k], 4) for k in ("psnr_face", "psnr_occluded", "psnr_expression")})
            model.train()
            emit(stage="trace", variant=name, step=step + 1, averaged_steps=average.steps, **row)

        info = train_hfm(out / "registration", out / f"model_{tag}", cfg, progress=False, log=None,
                         frames=None if a.reg_frames is None else slice(0, a.reg_frames), callback=trace)
        h = info["history"]
        model = load_hfm(out / f"model_{tag}")
        ev = evaluate_hmd(model, usage)
        emit(stage="heldout", variant=name, seed=a.seed, data_seed=a.data_seed, overrides=overrides, reg_frames=a.reg_frames or info["frames"], train_seconds=round(info["seconds"], 1), gaussians=info["n_gaussians"],
             loss_first=round(float(np.mean([r["loss"] for r in h[:20]])), 4),
             loss_last=round(float(np.mean([r["loss"] for r in h[-20:]])), 4),
             dropped_children=info["dropped_children"], **{k: round(v, 4) for k, v in ev.items()})
        if name == "full" and a.reg_frames is None and not overrides:
            c = usage.camera
            for s in (1, 2):
                cam = Camera(c.fx * s, c.fy * s, c.cx * s, c.cy * s, c.width * s, c.height * s, c.R, c.t)
                remove_hmd(model, usage, camera=cam)  # warm-up
                _, times = remove_hmd(model, usage, camera=cam)
                emit(stage="fps", variant=name, res=c.width * s, fps=round(float(1 / np.median(times)), 1),
                     ms_per_frame=round(1000 * float(np.median(times)), 1), threads=torch.get_num_threads())
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    from geoface.errors import GeofaceError
    try:
        sys.exit(main())
    except GeofaceError as e:
        print(f"eval_hfm: error: {e}", file=sys.stderr)
        sys.exit(2)
