#!/usr/bin/env python
"""HFM-GS and THGS on real clips, scored on the held-out last 20 % against the trivial baselines
(:mod:`geoface.avatar.protocol`): nothing from a renderer — frames, masks, landmarks, head track
and camera all come from ``geoface capture`` on the clip itself.

    python bench/eval_real_avatars.py CLIP.mp4|ict:SEED [...] --work DIR [--res 256] [--hfm-iters 2000]
        [--thgs-iters 3000] [--only baselines|hfm|thgs] [--out FILE]

``ict:SEED``: an ICT-FaceKit person rendered talking (``talk synth --head ict``'s generator, 8 s at
25 fps, 512²), given to ``geoface capture`` as its frames and sound alone — the same protocol on a
clip whose pictures the docs may show (the real clips' terms keep theirs out).

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
  audio). Lip sync: the mouth's opening found by looking (MediaPipe on each predicted frame: the
  inner lips' gap over the eye corners' distance) correlated with the real frames' (found the
  same way) and with the sound's loudness.

Each line: PSNR/SSIM per region (dB), the per-frame occluded / face PSNR (to show where a method
wins and loses), seconds to train, the machine. A clip without sound has no THGS row.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def mouth_gaps(frames: np.ndarray) -> np.ndarray:
    """The mouth's opening in each frame, found by looking: MediaPipe's face mesh on the frame,
    the inner lips' gap (iBUG 62–66) over the eye corners' distance (36–45); nan where no face."""
    from geoface.track import facemesh_points, ibug68_from_mediapipe

    pts = facemesh_points(list(np.round(np.clip(frames, 0, 1) * 255).astype(np.uint8)), video=False, quiet=True)
    idx, w = ibug68_from_mediapipe()
    p68 = np.einsum("tkjd,kj->tkd", pts[:, idx], w)
    return np.linalg.norm(p68[:, 62] - p68[:, 66], axis=-1) / np.linalg.norm(p68[:, 36] - p68[:, 45], axis=-1)


def _lipsync(preds: np.ndarray, gt_gaps: np.ndarray, env: np.ndarray | None) -> dict:
    """Lip sync: the predicted mouth's opening (:func:`mouth_gaps`) against the real frames' and
    against the sound's loudness."""
    g = mouth_gaps(preds)

    def corr(a, b):
        ok = np.isfinite(a) & np.isfinite(b)
        return float(np.corrcoef(a[ok], b[ok])[0, 1]) if ok.sum() > 2 and np.std(a[ok]) > 0 and np.std(b[ok]) > 0 else 0.0

    out = {"mouth_gap_corr_real": round(corr(g, gt_gaps), 3), "mouth_found": int(np.isfinite(g).sum())}
    if env is not None:
        out.update(lipsync_corr=round(corr(g, env), 3), lipsync_corr_real=round(corr(gt_gaps, env), 3))
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
    from geoface.capture import Capture

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
        name = clip.replace(":", "_") if clip.startswith("ict:") else Path(clip).stem
        work = Path(a.work) / name
        cap_dir = work / "capture"
        if not (cap_dir / "meta.json").is_file():
            if clip.startswith("ict:"):
                from geoface.thgs.ict import make_ict_talking

                talk = work / "render"
                if not (talk / "audio.wav").is_file():
                    make_ict_talking(talk, seconds=8.0, res=512, seed=int(clip[4:]), emote=1.0, quiet=True)
                capture_clip(talk / "frames", cap_dir, res=a.res, fps=25, audio=talk / "audio.wav", overlay=False,
                             quiet=True)
            else:
                capture_clip(clip, cap_dir, res=a.res, overlay=False, quiet=True)
        split = work / "split"
        if not (split / "test" / "meta.json").is_file():
            P.split_capture(cap_dir, split, quiet=True)
        te = Capture(split / "test")
        gt = te.images("gt", rgb=True)
        shown = te.frames()
        regs = P.regions(split / "test")
        hmd = regs["occluded"][..., None]
        gt_gaps = mouth_gaps(gt)
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
                _row(emit, base, method, "thgs", P.score_regions(pred, gt, regs), _lipsync(pred, gt_gaps, env))
        if "hfm" in only:
            from geoface.hfm import HFMConfig, load_hfm, train_hfm
            from geoface.hfm.data import load_video
            from geoface.hfm.usage import remove_hmd

            mdir = work / f"hfm_{a.hfm_iters}"
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
            # how far training moved the training frames' tracked head poses (the held-out frames keep theirs)
            tr_idx = np.arange(len(data) - len(idx))
            d_rot = np.degrees(model.d_rot.detach().numpy()[tr_idx, 0])
            d_tr = model.d_transl.detach().numpy()[tr_idx] * 1000
            _row(emit, base, "thgs", "thgs", P.score_regions(R, gt, regs),
                 {**_lipsync(R, gt_gaps, env), "iters": a.thgs_iters, "train_s": secs,
                  "fps": round(float(1 / np.median(times)), 1),
                  "pose_correction_rot_std_deg": np.round(d_rot.std(0), 2).tolist(),
                  "pose_correction_transl_std_mm": np.round(d_tr.std(0), 1).tolist()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
