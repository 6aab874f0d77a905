#!/usr/bin/env python
"""HFM-GS and THGS on real clips, scored on the held-out last 20 % against the trivial baselines
(:mod:`geoface.avatar.protocol`): nothing from a renderer — frames, masks, landmarks, head track
and camera all come from ``geoface capture`` on the clip itself.

    python bench/eval_real_avatars.py CLIP.mp4 [CLIP.mp4 ...] --work DIR [--res 256] [--hfm-iters 2000]
        [--thgs-iters 3000] [--only baselines|hfm|thgs] [--out FILE]

Per clip: ``geoface capture`` (``DIR/<clip>/capture``, reused when there), the time split
(``DIR/<clip>/split``: ``train/``, ``test/`` with a headset drawn over the test frames), then one
JSON line per method and protocol:

* ``protocol: hfm`` — the headset's pixels restored, everything else the test frame itself;
  scored over the occluded region (the pixels the headset hides) and the person. Methods:
  ``nearest_frame`` and ``mean_face`` (the baselines), ``hfm_gs`` with the head pose tracked
  (``usage_poses: file``; the tracked poses stand in for a headset's own tracking) and read from the
  lower-face crop (``image``; the paper's latent).
* ``protocol: thgs`` — the whole frame predicted; scored over the face (inside the 468 landmarks'
  oval) and the mouth box. Methods: the two baselines and ``thgs`` driven by the clip's own sound
  and the tracked poses and expressions (the expressions the tracker measured; the mouth from the
  audio). Lip sync: the mouth's opening (:func:`geoface.thgs.eval.mouth_openness` in the real
  mouth box) correlated with the sound's loudness and with the real frames' opening.

Each line: PSNR/SSIM per region (dB), the per-frame occluded / face PSNR (to show where a method
wins and loses), seconds to train, the machine. A clip without sound has no THGS row.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def _lipsync(preds: np.ndarray, gt: np.ndarray, pts68: np.ndarray, env: np.ndarray | None) -> dict:
    from geoface.thgs.eval import mouth_openness

    H, W = gt.shape[1:3]
    o_p, o_g = [], []
    for j in range(len(gt)):
        mp = pts68[j, 48:68]
        pad = 0.25 * (mp[:, 0].max() - mp[:, 0].min())
        x0, x1 = (int(np.clip(v, 0, W)) for v in (mp[:, 0].min() - pad, mp[:, 0].max() + pad + 1))
        y0, y1 = (int(np.clip(v, 0, H)) for v in (mp[:, 1].min() - pad, mp[:, 1].max() + pad + 1))
        o_p.append(mouth_openness(preds[j], (y0, y1, x0, x1)))
        o_g.append(mouth_openness(gt[j], (y0, y1, x0, x1)))

    def corr(a, b):
        return float(np.corrcoef(a, b)[0, 1]) if np.std(a) > 0 and np.std(b) > 0 else 0.0

    out = {"mouth_open_corr_real": round(corr(o_p, o_g), 3)}
    if env is not None:
        out.update(lipsync_corr=round(corr(o_p, env), 3), lipsync_corr_real=round(corr(o_g, env), 3))
    return out


def _row(emit, base, method, protocol, scores, extra=None):
    keep = ("occluded", "person") if protocol == "hfm" else ("face", "mouth")
    r = {**base, "protocol": protocol, "method": method}
    for k in keep:
        r[f"psnr_{k}"] = round(scores[f"psnr_{k}"], 2)
        r[f"ssim_{k}"] = round(scores[f"ssim_{k}"], 4)
    r[f"psnr_{keep[0]}_frames"] = scores[f"psnr_{keep[0]}_frames"]
    emit({**r, **(extra or {})})


def main(argv=None) -> int:
    from _results import emitter

    from geoface.avatar import protocol as P
    from geoface.avatar.audio import envelope, read_wav
    from geoface.avatar.clip import capture_clip
    from geoface.capture import Capture, read_landmarks

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips", nargs="+")
    ap.add_argument("--work", required=True)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--hfm-iters", type=int, default=2000)
    ap.add_argument("--thgs-iters", type=int, default=3000)
    ap.add_argument("--only", choices=("baselines", "hfm", "thgs"), nargs="+", default=None)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    emit = emitter(a.out)
    only = set(a.only or ("baselines", "hfm", "thgs"))
    machine = f"{platform.node()}: {os.cpu_count()} cores, {a.device}"
    import torch

    torch.set_num_threads(a.threads)
    for clip in a.clips:
        name = Path(clip).stem
        work = Path(a.work) / name
        cap_dir = work / "capture"
        if not (cap_dir / "meta.json").is_file():
            capture_clip(clip, cap_dir, res=a.res, overlay=False, quiet=True)
        split = work / "split"
        if not (split / "test" / "meta.json").is_file():
            P.split_capture(cap_dir, split, quiet=True)
        te = Capture(split / "test")
        gt = te.images("gt", rgb=True)
        shown = te.frames()
        regs = P.regions(split / "test")
        hmd = regs["occluded"][..., None]
        pts68, _ = read_landmarks(split / "test" / P.TRUTH / "landmarks.json", len(gt))
        env = None
        if (split / "test" / "audio.wav").is_file():
            x, sr = read_wav(split / "test" / "audio.wav")
            env = envelope(x, sr, float(te.meta().get("fps", 25.0)), len(gt))
        base = {"clip": name, "res": a.res, "train_frames": len(Capture(split / "train")), "test_frames": len(gt),
                "split": "last 20 %", "inputs": "tracked (geoface capture)", "machine": machine}
        if "baselines" in only:
            nf, pick = P.nearest_frame(split / "train", split / "test")
            mf = P.mean_face(split / "train", len(gt))
            for method, pred in (("nearest_frame", nf), ("mean_face", mf)):
                _row(emit, base, method, "hfm", P.score_regions(np.where(hmd, pred, shown), gt, regs))
                _row(emit, base, method, "thgs", P.score_regions(pred, gt, regs), _lipsync(pred, gt, pts68, env))
        if "hfm" in only:
            from geoface.hfm import HFMConfig, load_hfm, train_hfm
            from geoface.hfm.data import load_video
            from geoface.hfm.usage import remove_hmd

            mdir = work / f"hfm_{a.hfm_iters}"
            t0 = time.perf_counter()
            if not (mdir / "config.json").is_file():
                info = train_hfm(split / "train", mdir, HFMConfig(iters=a.hfm_iters), progress=False,
                                 log=lambda *x, **k: None, device=a.device)
                secs = info["seconds"]
            else:
                secs = None
            model = load_hfm(mdir)
            video = load_video(split / "test")
            for poses in ("file", "image"):
                R, times = remove_hmd(model, video, poses=poses)
                _row(emit, base, f"hfm_gs_poses_{poses}", "hfm", P.score_regions(np.where(hmd, R, shown), gt, regs),
                     {"iters": a.hfm_iters, "train_s": secs, "fps": round(float(1 / np.median(times)), 1)})
            del t0
        if "thgs" in only and env is not None:
            from geoface.thgs.data import load_talking
            from geoface.thgs.inference import load_thgs, render_frames
            from geoface.thgs.model import THGSConfig
            from geoface.thgs.train import train_heldout_split, train_thgs

            mdir = work / f"thgs_{a.thgs_iters}"
            secs = None
            if not (mdir / "config.json").is_file():
                info = train_thgs(cap_dir, mdir, THGSConfig(iters=a.thgs_iters, heldout=P.TEST_FRACTION),
                                  progress=False, log=lambda *x, **k: None, device=a.device)
                secs = info["seconds"]
            model = load_thgs(mdir)
            data = load_talking(cap_dir)
            _, idx = train_heldout_split(len(data), P.TEST_FRACTION)
            assert len(idx) == len(gt), (len(idx), len(gt))
            R, times = render_frames(model, data.camera, data.rot, data.transl, data.expr, data.audio, idx)
            _row(emit, base, "thgs", "thgs", P.score_regions(R, gt, regs),
                 {**_lipsync(R, gt, pts68, env), "iters": a.thgs_iters, "train_s": secs,
                  "fps": round(float(1 / np.median(times)), 1)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
