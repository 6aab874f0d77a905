#!/usr/bin/env python
"""Evaluate THGS on a synthetic talking head: full model, without LEB, without SAAM.

    python bench/eval_thgs.py [--seconds 8] [--res 128] [--vertices 6000] [--iters 3000]
                              [--head procedural|ict] [--perturb 3,5] [--saam-from 0.4] [--seed 0] [--out DIR] [--quick]
                              [--lr-pose R] [--pose-decay F] [--device cpu|cuda]

1. writes the synthetic talking data (``geoface talk synth -o DIR [--head ict]``): a speech-like WAV
   drives the jaw and lips; the tracker poses hold only the head pose and the non-mouth
   expressions; with ``--perturb DEG,MM`` (ICT heads) also the same capture with each frame's
   tracked head pose off by that much, on which the full model is trained too, and the head
   pose error of its training frames is reported before and after its learned corrections;
2. trains each variant on the first 80% of the frames (same seed and steps). The paper's stage
   starts (1.5K/15K/25K/50K) are scaled so that SAAM starts at ``--saam-from`` of the run;
3. on the held-out 20%: PSNR/SSIM over the person, PSNR of the mouth rectangle, lip sync (the
   correlation of the rendered mouth's openness with the audio loudness envelope, next to the
   real frames' own correlation), the spread (std) of the rendered mouth openness next to the
   real frames', and the rendering FPS on CPU.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {"full": {}, "no_leb": {"use_leb": False}, "no_saam": {"use_saam": False},
            "no_audio_pose": {"use_audio_pose": False}, "no_landmarks": {"lambda_landmarks": 0.0},
            "landmarks_move_poses": {"landmarks_pose": True}, "audio_window": {"audio_window": 2}, "no_audio_window": {"audio_window": 0},
            "prefit": {"artic_prefit": True}}


def main(argv=None) -> int:
    import torch

    from geoface.thgs.model import PAPER_STAGES, THGSConfig
    from geoface.thgs.inference import load_thgs
    from geoface.thgs.train import train_thgs
    from geoface.thgs.eval import evaluate_thgs
    from geoface.thgs.data import load_talking, make_synthetic_talking

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--vertices", type=int, default=6000)
    ap.add_argument("--iters", type=int, default=3000)
    ap.add_argument("--head", choices=("procedural", "ict"), default="procedural")
    ap.add_argument("--perturb", default=None, metavar="DEG,MM",
                    help="ict: also train the full model on a copy whose tracked poses are off by this much")
    ap.add_argument("--tracked", action="store_true",
                    help="also train the full model on the capture's landmarks and masks from a real tracker "
                         "(geoface track: MediaPipe) instead of the renderer's; scored on the same frames")
    ap.add_argument("--tracked-poses", action="store_true",
                    help="also train the full model on the tracked capture with its head poses fitted to the tracked "
                         "landmarks (geoface.thgs.data.fit_head_poses) instead of the capture's own")
    ap.add_argument("--data-seed", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0, help="model seed (initialisation, frame order)")
    ap.add_argument("--saam-from", type=float, default=0.1)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--lambda-landmarks", type=float, default=None,
                    help="weight of the mouth-landmark loss for every variant but no_landmarks (default: THGSConfig's)")
    ap.add_argument("--out", default="/tmp/geoface_eval_thgs")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--lr-pose", type=float, default=None, help="THGSConfig.lr_pose (default: its default)")
    ap.add_argument("--pose-decay", type=float, default=None, help="THGSConfig.pose_decay (default: its default)")
    ap.add_argument("--device", default="cpu", help="training device: cpu or cuda (scoring runs on the CPU)")
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
    runs = [(name, data_dir, VARIANTS[name]) for name in a.variants.split(",") if name]
    kw = dict(seconds=a.seconds, res=a.res, n_vertices=a.vertices, seed=a.data_seed, quiet=True)
    if a.head == "ict":
        from geoface.thgs.ict import make_ict_talking as make
    else:
        make = make_synthetic_talking
    if not (data_dir / "poses.npz").is_file():
        make(data_dir, **kw)
    if a.perturb:
        pert = tuple(float(x) for x in a.perturb.split(","))
        if a.head != "ict":
            raise SystemExit("eval_thgs: --perturb needs --head ict")
        if not (out / "data_perturbed" / "poses.npz").is_file():
            from geoface.thgs.ict import perturb_capture

            perturb_capture(data_dir, out / "data_perturbed", pert, seed=a.data_seed)  # the same video, other poses
        runs.append(("full_perturbed", out / "data_perturbed", {}))
    if a.tracked or a.tracked_poses:
        if not (out / "data_tracked" / "poses.npz").is_file():
            from geoface.track import track_capture

            tr = track_capture(data_dir, out / "data_tracked", overwrite=True, quiet=True)
            truth = json.loads((data_dir / "landmarks.json").read_text())
            got = np.asarray(json.loads((out / "data_tracked" / "landmarks.json").read_text())["points"])
            truth_pts = np.asarray(truth["points"])
            emit(stage="tracking", frames=len(tr.found), found=int(tr.found.sum()), landmarks=len(truth.get("names") or got[0]),
                 landmark_error_px=round(float(np.linalg.norm(got - truth_pts, axis=-1).mean()), 3))
        if a.tracked:
            runs.append(("full_tracked", out / "data_tracked", {}))
    if a.tracked_poses:
        tp = out / "data_tracked_poses"
        if not (tp / "poses_true.npz").is_file() or not (tp / "fit.json").is_file():
            import shutil

            from geoface.avatar.template import Template
            from geoface.thgs.data import fit_head_poses
            from geoface.thgs.eval import head_pose_errors

            if tp.exists():
                shutil.rmtree(tp)
            shutil.copytree(out / "data_tracked", tp)
            fit = fit_head_poses(tp)
            with np.load(tp / "poses.npz") as z, np.load(data_dir / "poses_true.npz") as zt:
                err = head_pose_errors(Template.load(tp / "template.npz"), z["rot"], z["transl"], zt["rot"], zt["transl"])
            (tp / "fit.json").write_text(json.dumps({**fit, **err}))
        fit = json.loads((tp / "fit.json").read_text())
        emit(stage="tracked_poses", **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in fit.items()})
        runs.append(("full_tracked_poses", tp, {}))
    emit(stage="data", seconds=round(time.perf_counter() - t, 1))
    rnd = lambda v: {k: rnd(x) for k, x in v.items()} if isinstance(v, dict) else round(v, 4)  # noqa: E731
    loaded = {}
    for name, ddir, opts in runs:
        lam = {k: v for k, v in (("lambda_landmarks", a.lambda_landmarks), ("lr_pose", a.lr_pose),
                                 ("pose_decay", a.pose_decay)) if v is not None}
        cfg = THGSConfig(iters=a.iters, stage_scale=scale, seed=a.seed, **{**lam, **opts})
        info = train_thgs(ddir, out / f"model_{name}", cfg, progress=False, device=a.device)
        h = info["history"]
        score_dir = data_dir if name == "full_tracked" else ddir  # scored against the true frames and masks
        if score_dir not in loaded:  # the variants on one capture share its frames in memory
            loaded[score_dir] = load_talking(score_dir)
        ev = evaluate_thgs(load_thgs(out / f"model_{name}"), loaded[score_dir])
        emit(stage="heldout", variant=name, seed=a.seed, train_seconds=round(info["seconds"], 1), gaussians=info["n_gaussians"],
             loss_first=round(float(np.mean([r["loss"] for r in h[:20]])), 4),
             loss_last=round(float(np.mean([r["loss"] for r in h[-20:]])), 4), artic_prefit=rnd(info["artic_prefit"]),
             **rnd(ev))
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    from geoface.errors import GeofaceError
    try:
        sys.exit(main())
    except GeofaceError as e:
        print(f"eval_thgs: error: {e}", file=sys.stderr)
        sys.exit(2)
