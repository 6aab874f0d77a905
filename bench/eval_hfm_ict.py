#!/usr/bin/env python
"""HFM-GS on ICT-FaceKit people without the head-pose file: held-out identities, paired variants.

    python bench/eval_hfm_ict.py data --out DIR [--val 10 --test 11,12,13] [--frames 200 --usage 50] [--rom 3]
    python bench/eval_hfm_ict.py track --out DIR [--splits test] [--head-track]   # then --variants tracked
    python bench/eval_hfm_ict.py head_track_usage --out DIR [--splits val,test]   # after run --variants tracked_head_track
    python bench/eval_hfm_ict.py run --out DIR [--splits test] [--seeds 0,1] [--jobs 4] [--device cuda]
    python bench/eval_hfm_ict.py run --out DIR --group test/0/oracle,full --group val/0,1/full,map_theta/10 ...
    python bench/eval_hfm_ict.py poses --out DIR [--splits val,test]
    python bench/eval_hfm_ict.py calibration --out DIR --group val/0/full/10,22,23,24 [--grid 0:0,8:0.01,...]
    python bench/eval_hfm_ict.py table --out DIR

``data`` writes one capture per identity seed (:func:`geoface.hfm.ict.make_ict_hmd`: a
talking, emoting, lit ICT person, registration and usage videos of different sequences) under
``DIR/data/<split>_<seed>``.  ``run`` trains, for each capture and model seed, the variants

* ``oracle``   — Full, registered and used with the true head poses (``head_poses.npz``);
* ``tracked``  — Full with no pose file on the copy of the capture that the ``track`` stage wrote:
  landmarks and person masks detected by MediaPipe on the frames (:mod:`geoface.track`) instead of
  the renderer's, headset masks segmented from the usage frames, registration and usage; scored
  against the same true frames (``gt/``, ``hmd_masks_true/``); ``tracked_pose_refine``: the same with
  the registration poses corrected per frame by the image loss; ``tracked_true_poses``: the same
  copy registered and used with the true head poses (what the tracked landmarks and masks cost alone);
  ``tracked_head_track``: the copy that ``track --head-track`` wrote (``DIR/data_head_track``),
  registered with the ICT head track's poses instead of the landmarks' PnP and used as ``tracked``;
* ``full``     — Full with no pose file: registration poses fitted to the landmarks (PnP), the
  usage pose read from the lower-face crop (the pose MLP trained during registration);
* ``no_gaussian_feature_mapping``, ``no_global_pose`` — the paper's ablations, no pose file;
* ``map_theta``, ``gm_xsr``, ``pm_per_component``, ``split_margin`` — Full with one of the paper's
  elements that the defaults leave out (:data:`PAPER`), for the choice on the validation split;
* ``pose_residual``, ``no_pose_residual``, ``reg_lower``, ``reg_lower_no_pose_residual``, ``pose_refine`` —
  Full with or without the residual pose MLP (the default leaves it out), with registration poses
  fitted to the lower landmarks, or both, or with the registration poses corrected per frame by the
  image loss (:data:`OURS`; validation); ``reg_stable``: registration poses fitted to the stable landmarks;
  ``pose_head_detach``: the crop's pose MLP learns alone, out of the encoder's training (and
  ``oracle_pose_head_detach``, the same registered and used with the true poses);

and scores each on the usage video (PSNR/SSIM: whole face, the region the headset hides, its
expression region; the occluded region's interior and its outline, the face pixels within 1 px
of the face's edge); the no-file models with the usage pose fitted to the landmarks below the
headset and calibrated to the registration frame (``usage_poses: landmarks``; a model trained
before the calibration existed gets it from its registration video first), the same uncalibrated
(``landmarks_uncalibrated``), read from the crop alone (``image``) and, to separate what the pose
estimate costs, the true one (``file``).  One JSON line per score in ``DIR/results.jsonl``;
``calibration`` scores trained models with each calibration setting of ``--grid``
(components:ridge[:w][:s][:eN][:hR]: w weighs the landmarks, s fits the usage poses to the 8 stable lower landmarks,
eN sees each registration frame N more times with
generic expressions, hR corrects the usage poses by the headset masks, :mod:`geoface.hfm.headset_pose`,
with expression-map ridge R; each row also says how far those usage poses put the upper and the lower landmarks
from where the true poses put them, ``upper_px`` / ``lower_px``);
``poses`` scores the head poses alone against the truth: registration poses fitted to the 68
landmarks' rigid set (and to the stable and the lower set), usage poses fitted to those below the headset.  ``table`` prints means, the pairs, and whole face / occluded PSNR per person and model seed.  Choose settings with ``--splits val``; report ``test``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {"oracle": ("full", "file"), "full": ("full", "landmarks"),
            "no_gaussian_feature_mapping": ("no_gaussian_feature_mapping", "landmarks"),
            "no_global_pose": ("no_global_pose", "landmarks")}
#: the paper's elements that the defaults depart from, each alone on top of Full (no pose file);
#: measured on the validation split before any becomes a default
PAPER = {"map_theta": {"map_theta": True}, "gm_xsr": {"gm_input": "xsr"},
         "pm_per_component": {"pm_per_component": True}, "split_margin": {"split_margin": 0.002}}
#: choices of ours, each alone on top of Full (no pose file), for the validation split
OURS = {"pose_residual": {"pose_residual": True}, "no_pose_residual": {"pose_residual": False}, "reg_lower": {"registration_landmarks": "lower"},
        "reg_lower_no_pose_residual": {"registration_landmarks": "lower", "pose_residual": False},
        "pose_refine": {"pose_refine": True}, "reg_stable": {"registration_landmarks": "stable"},
        "pose_head_detach": {"image_pose_detach": True}, "oracle_pose_head_detach": {"image_pose_detach": True}}
VARIANTS.update({k: ("full", "landmarks") for k in {**PAPER, **OURS}})
VARIANTS["oracle_pose_head_detach"] = ("full", "file")  # registered and used with the true poses
VARIANTS["tracked"] = ("full", "landmarks")  # Full on the capture's copy tracked by geoface.track (DIR/data_tracked)
OURS["tracked_pose_refine"] = {"pose_refine": True}  # the same, registration poses corrected by the image loss
VARIANTS["tracked_pose_refine"] = ("full", "landmarks")
# the tracked copy registered and used with the true head poses (an ablation: what the tracked
# landmarks and masks cost with the poses exact)
VARIANTS["tracked_true_poses"] = ("full", "file")
# the tracked copy registered with the ICT head track's poses (``track --head-track``: its
# registration head_poses.npz), used with the poses fitted to the lower landmarks, as ``tracked``
VARIANTS["tracked_head_track"] = ("full", "file")
#: variants registered with a pose file but used, as the no-file ones, with every usage pose source
REGISTERED_WITH_FILE = {"tracked_head_track"}
MAIN = ["oracle", "full", "no_gaussian_feature_mapping", "no_global_pose"]


def _data(a) -> None:
    from geoface.hfm.ict import make_ict_hmd

    for split, seeds in (("val", a.val), ("test", a.test)):
        for s in seeds:
            d = Path(a.out) / "data" / f"{split}_{s}"
            if (d / "usage" / "meta.json").is_file():
                continue
            t0 = time.time()
            make_ict_hmd(d, frames=a.frames, usage_frames=a.usage, res=a.res, seed=s, rom=a.rom, quiet=True)
            print(json.dumps({"stage": "data", "split": split, "seed": s, "seconds": round(time.time() - t0, 1)}), flush=True)


def _track(a) -> None:
    """Each capture's copy in ``DIR/data_tracked/<split>_<seed>`` whose landmarks and person masks
    come from the face tracker (MediaPipe; :func:`geoface.track.track_capture`) run on its frames,
    registration and usage alike (the usage frames wear the headset); one row per video with the
    tracker's error against the capture's true points (its own landmarks.json) and the masks'
    IoU with the renderer's; a capture tracked before is not tracked again (its row is)."""
    from geoface.track import track_capture

    data = Path(a.data) if a.data else Path(a.out) / "data"
    for split, seeds in (("val", a.val), ("test", a.test)):
        if split not in a.splits:
            continue
        for s in seeds:
            for which in ("registration", "usage"):
                src = data / f"{split}_{s}" / which
                dst = Path(a.out) / "data_tracked" / f"{split}_{s}" / which
                if not (src / "meta.json").is_file():
                    raise SystemExit(f"{src}: no capture; run the data stage first")
                t0 = time.time()
                stale = (src / "hmd_masks").is_dir() and not (dst / "hmd_masks_true").is_dir()  # before headset masks
                if (dst / "landmarks.json").is_file() and not stale:  # tracked before: its row again, from the files
                    found = np.asarray(json.loads((dst / "landmarks.json").read_text()).get("found") or [], bool)
                    seconds = None
                else:
                    found = track_capture(src, dst, quiet=True, overwrite=dst.exists()).found
                    seconds = round(time.time() - t0, 1)
                truth = np.asarray(json.loads((src / "landmarks.json").read_text())["points"], np.float64)
                got = np.asarray(json.loads((dst / "landmarks.json").read_text())["points"], np.float64)
                err = np.linalg.norm(got - truth, axis=-1)
                true_masks = np.stack([_read_mask(f) for f in sorted((src / "masks").glob("*.png"))])
                got_masks = np.stack([_read_mask(f) for f in sorted((dst / "masks").glob("*.png"))])
                iou = (true_masks & got_masks).sum((1, 2)) / np.maximum((true_masks | got_masks).sum((1, 2)), 1)
                headset = {}
                if (dst / "hmd_masks_true").is_dir():  # the headset segmented from the frames vs the renderer's
                    hm_true = np.stack([_read_mask(f) for f in sorted((dst / "hmd_masks_true").glob("*.png"))])
                    hm = np.stack([_read_mask(f) for f in sorted((dst / "hmd_masks").glob("*.png"))])
                    hi = (hm_true & hm).sum((1, 2)) / np.maximum((hm_true | hm).sum((1, 2)), 1)
                    headset = {"headset_iou": round(float(hi.mean()), 4), "headset_iou_min": round(float(hi.min()), 4)}
                print(json.dumps({"stage": "tracking", "split": split, "data_seed": s, "video": which, "frames": len(truth),
                                  "found": int(found.sum()), "landmarks": int(got.shape[1]),
                                  "landmark_error_px": round(float(err.mean()), 3),
                                  "landmark_error_p95_px": round(float(np.percentile(err, 95)), 3),
                                  "mask_iou": round(float(iou.mean()), 4), **headset, "seconds": seconds}), flush=True)
            if a.head_track:
                _head_track_copy(Path(a.out), f"{split}_{s}", data / f"{split}_{s}" / "registration")


def _head_track_copy(out: Path, name: str, truth_dir: Path) -> None:
    """``OUT/data_head_track/<name>``: the tracked copy with registration poses from the ICT head
    track (:func:`geoface.track.head_track.fit_head_track` on MediaPipe's 468 points of the
    frames, through the capture's camera, refined against the pixels): the clip's head motion from
    the track, placed on the capture's head mesh by the one rigid offset and scale that best lay
    the track on the poses fitted to the tracked landmarks (PnP, ``tracked``'s poses) over all
    frames. One row: the poses' error against the truth, as the runs score it."""
    import shutil

    from geoface.capture import write_head_poses
    from geoface.hfm.data import load_video

    src, dst = out / "data_tracked" / name, out / "data_head_track" / name
    if (dst / "registration" / "head_poses.npz").is_file():
        return
    t0 = time.time()
    reg, place, Rw, tw, pivot, Rp, tp = _registration_head_track(src / "registration")
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    write_head_poses(dst / "registration", Rw, tw, pivot)
    place.save(dst / "registration" / "head_track.npz")  # the usage track is placed the same (head_track_usage)
    true = load_video(truth_dir).poses
    rv, dt = _pose_offsets(true, Rw, tw, pivot)
    rv0, dt0 = _pose_offsets(true, Rp, tp, pivot)
    print(json.dumps({"stage": "head_track", "data": name, "frames": len(reg), "focal": round(float(reg.camera.fx), 1),
                      "registration_pose_deg": round(_centred_rms(rv), 3), "registration_pose_mm": round(_centred_rms(dt), 3),
                      "pnp_pose_deg": round(_centred_rms(rv0), 3), "pnp_pose_mm": round(_centred_rms(dt0), 3),
                      "seconds": round(time.time() - t0, 1)}), flush=True)


def _registration_head_track(reg_dir: Path):
    """The registration video's ICT head track (refined against the pixels, through the capture's
    camera) and its placement on the capture's head mesh: ``(video, place, R, t, pivot, R_pnp,
    t_pnp)``, with ``place(track) → (R, t)`` the one turn, shift and scale that best lay this
    track on the landmarks' PnP poses over all frames, applied to any track of the same identity
    and camera."""
    from scipy.spatial.transform import Rotation

    from geoface.hfm.data import load_video
    from geoface.hfm.train import registration_poses
    from geoface.mesh.io import load_mesh
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import fit_head_track

    reg = load_video(reg_dir, need_mesh=True)
    registration_poses(reg, "landmarks", None, load_mesh(reg.mesh_path))  # the tracked variant's PnP poses
    Rp, tp, pivot = reg.poses
    cam = reg.camera
    H, W = reg.frames.shape[1:3]
    pts = _facemesh(reg)
    tr = fit_head_track(pts, (W, H), focal=float(cam.fx), quiet=True)
    tr, _ = refine_photometric(tr, reg.frames, reg.masks.astype(np.float32), pts, quiet=True)
    C, c0 = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    # the mesh's turn in the camera, C R_k, is the track's turn R_k times one constant Q
    Q = Rotation.from_matrix(np.einsum("tji,jk,tkl->til", tr.R, C, Rp)).mean().as_matrix()
    # the pivot in the camera, c_k = C (pivot + t_k) + cam.t, is s t_k + R_k u (a head s times
    # bigger s times further away projects the same)
    c = (pivot + tp) @ C.T + c0
    A = np.concatenate([tr.t.reshape(-1, 1), tr.R.reshape(-1, 3)], 1)
    su = np.linalg.lstsq(A, c.reshape(-1), rcond=None)[0]

    place = _placement(C, c0, Q, su, pivot, tr.identity)
    Rw, tw = place(tr)
    return reg, place, Rw, tw, pivot, Rp, tp


def _placement(C, c0, Q, su, pivot, identity):
    """``place(track) → (R, t)``: a track of this person and camera on the capture's head mesh
    (:func:`_registration_head_track`); ``place.save(path)`` keeps it (``head_track.npz``)."""
    def place(track):
        R = np.einsum("ji,tjk,kl->til", C, track.R, Q)
        t = (su[0] * track.t + track.R @ su[1:] - c0) @ C - pivot
        return R, t

    place.identity, place.pivot = np.asarray(identity, np.float64), np.asarray(pivot, np.float64)
    place.save = lambda path: np.savez(path, C=C, c0=c0, Q=Q, su=su, pivot=pivot, identity=place.identity)
    return place


def _load_placement(path: Path):
    """The placement :func:`_placement` saved at ``path``."""
    with np.load(path) as z:
        return _placement(z["C"], z["c0"], z["Q"], z["su"], z["pivot"], z["identity"])


def _usage_head_track(a) -> None:
    """``head_track_usage``: the usage video's poses from the same head track as the registration's
    (``track --head-track``), scored with ``tracked_head_track``'s model, one row each:

    * ``tracked_head_track_usage``: the ICT head with the registration track's identity, fitted to
      MediaPipe's points below the headset (:func:`geoface.track.head_track.below_headset`) through
      the capture's camera, and placed on the head mesh as the registration track was;
    * ``tracked_head_track_usage_refined``: that track refined against the pixels below the headset
      (:func:`geoface.track.head_refine.refine_photometric` with ``region``: the person's mask less
      the segmented headset, dilated 3 px), then moved by the offset a track of the lower face
      alone has on the registration video (the same fit and refinement on its middle 60 frames,
      against the registration's own poses there: one turn and shift in the head's frame);
    * ``tracked_head_track_usage_aligned``: those poses aligned with the image by the avatar itself
      (:func:`geoface.hfm.align.align_poses`, 20 steps, with translation);
    * ``tracked_head_track_usage_landmarks_aligned``: the first poses aligned so (what the
      refinement adds).

    Writes ``DIR/data_head_track_usage/<name>`` (the head-track copy with the aligned usage poses)
    and the poses' error beside each score."""
    import shutil
    from dataclasses import replace

    import torch
    from scipy.ndimage import binary_dilation

    import geoface.track.head_track as HT
    from geoface.capture import write_head_poses
    from geoface.hfm import evaluate_hmd, load_hfm
    from geoface.hfm.align import align_poses
    from geoface.hfm.data import load_video

    data = Path(a.data) if a.data else Path(a.out) / "data"
    models = Path(a.models or Path(a.out) / "models")
    res = Path(a.out) / "results.jsonl"
    for split, seeds in (("val", a.val), ("test", a.test)):
        if split not in a.splits:
            continue
        for s in seeds:
            name = f"{split}_{s}"
            src, dst = Path(a.out) / "data_head_track" / name, Path(a.out) / "data_head_track_usage" / name
            t0 = time.time()
            saved = src / "registration" / "head_track.npz"
            same = None  # how far the registration poses made again are from the model's (when they are)
            if saved.is_file():  # kept by the track stage: the refined registration track is not made again
                place = _load_placement(saved)
            else:  # a copy made before the placement was kept: the registration track again (about 25 min)
                _, place, Rw, tw, _, _, _ = _registration_head_track(Path(a.out) / "data_tracked" / name / "registration")
                with np.load(src / "registration" / "head_poses.npz") as z:  # the poses the model was registered in
                    same = float(max(np.abs(z["R"] - Rw).max(), np.abs(z["t"] - tw).max()))
                place.save(saved)
            pivot = place.pivot
            use_v = load_video(src / "usage")
            true = load_video(data / name / "usage").poses
            model = load_hfm(models / f"{name}_tracked_head_track_s0")
            lower, region = HT.below_headset(place.identity)
            seen = use_v.masks & ~np.stack([binary_dilation(h, iterations=3) for h in use_v.hmd_masks])
            ut, rt, ref, _, t_refine = _lower_face_track(use_v, slice(None), seen, place.identity, lower, region)
            t_fit = time.time() - t0 - t_refine  # the loads and the face mesh's points count as the fit's, as before
            t1 = time.time()
            D, d = _lower_face_offset(place, src / "registration", lower, region)
            t_offset = time.time() - t1
            poses = {"tracked_head_track_usage": place(ut)}
            Rr, tr_ = place(rt)
            poses["tracked_head_track_usage_refined"] = (Rr @ D, tr_ + np.einsum("tij,j->ti", Rr, d))
            align_s = {}
            for src_v, v_name in (("tracked_head_track_usage_refined", "tracked_head_track_usage_aligned"),
                                  ("tracked_head_track_usage", "tracked_head_track_usage_landmarks_aligned")):
                t1 = time.time()
                with torch.enable_grad():
                    Ra, ta, _ = align_poses(model, use_v, (*poses[src_v], pivot), steps=20, translation=True, quiet=True)
                poses[v_name], align_s[v_name] = (Ra, ta), time.time() - t1
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(src, dst)
            write_head_poses(dst / "usage", *poses["tracked_head_track_usage_aligned"], pivot)
            lines = []
            for variant, (Ru, tu) in poses.items():
                rv, dt = _pose_offsets(true, Ru, tu, pivot)
                r = evaluate_hmd(model, replace(use_v, poses=(Ru, tu, pivot)), poses="file")
                lines.append({"stage": "head_track_usage", "data": name, "variant": variant, "frames": len(use_v),
                              "lower_points": int(lower.sum()), "registration_poses_reproduced": same,
                              "usage_pose_deg": round(_centred_rms(rv), 3), "usage_pose_mm": round(_centred_rms(dt), 3),
                              "usage_offset_deg": np.round(rv.mean(0), 3).tolist(), "usage_offset_mm": np.round(dt.mean(0), 2).tolist(),
                              "fit_s": round(t_fit, 1), "refine_s": round(t_refine, 1), "offset_s": round(t_offset, 1),
                              "align_s": round(align_s.get(variant, 0.0), 1),
                              "photo_err_before": round(float(np.nanmean(ref.before)), 4),
                              "photo_err_after": round(float(np.nanmean(ref.after)), 4)})
                lines.append({"stage": "score", "split": split, "data_seed": s, "seed": 0, "variant": variant, "usage_poses": "file",
                              **{k: (round(float(v), 4) if isinstance(v, (int, float)) else v) for k, v in r.items()}})
            with res.open("a") as f:
                for line in lines:
                    print(json.dumps(line), flush=True)
                    f.write(json.dumps(line) + "\n")


#: the registration frames (the middle ones) the lower face's offset is measured on
OFFSET_FRAMES = 60


def _lower_face_track(video, sl, seen, identity, lower, region):
    """The ICT head of ``identity`` tracked on frames ``sl`` of a loaded video from its lower face
    alone: fitted to MediaPipe's points ``lower`` through the capture's camera, then refined against
    the pixels of ``region`` where ``seen`` (T, H, W) holds, the other points unseen.
    ``(landmark track, refined track, the refinement's errors, fit seconds, refinement seconds)``."""
    import geoface.track.head_track as HT
    from geoface.track.head_refine import refine_photometric

    t0 = time.time()
    pts = _facemesh(video)[sl]
    frames = video.frames[sl]
    H, W = frames.shape[1:3]
    ut = HT.fit_head_track(pts, (W, H), focal=float(video.camera.fx), use=lower, identity=identity, quiet=True)
    t1 = time.time()
    rt, ref = refine_photometric(ut, frames, seen[sl].astype(np.float32), np.where(lower[None, :, None], pts, np.nan),
                                 identity=False, region=region, quiet=True)
    return ut, rt, ref, t1 - t0, time.time() - t1


def _lower_face_offset(place, reg_dir: Path, lower, region):
    """What a track of the lower face alone gets wrong on the registration video, where the whole
    face's track is known: the same fit (``use=lower``, the identity held) and refinement
    (``region``) on the middle :data:`OFFSET_FRAMES` frames, placed on the mesh, against the
    registration's own poses there. ``(D (3, 3), d (3,))``: the turn and the shift (metres) in the
    head's frame that take the lower face's poses onto the whole face's, on average."""
    from scipy.spatial.transform import Rotation

    from geoface.hfm.data import load_video

    reg = load_video(reg_dir)
    a = max((len(reg) - OFFSET_FRAMES) // 2, 0)
    sl = slice(a, a + OFFSET_FRAMES)
    _, lt, _, _, _ = _lower_face_track(reg, sl, reg.masks, place.identity, lower, region)
    Rl, tl = place(lt)
    Rw, tw = reg.poses[0][sl], reg.poses[1][sl]
    D = Rotation.from_matrix(np.einsum("tji,tjk->tik", Rl, Rw)).mean().as_matrix()
    d = np.einsum("tji,tj->ti", Rl, tw - tl).mean(0)
    return D, d


def _capture_dir(out, data: Path, variant: str) -> Path:
    """Where a variant's captures are: the tracked copies (the head track's for ``tracked_head_track``) or ``data``."""
    if not variant.startswith("tracked"):
        return data
    return Path(out) / ("data_head_track" if variant == "tracked_head_track" else "data_tracked")


def _facemesh(video) -> np.ndarray:
    """MediaPipe's 468 points on a loaded video's frames (float in [0, 1]), tracked frame to frame."""
    from geoface.track import facemesh_points

    return facemesh_points([np.round(f * 255).astype(np.uint8) for f in video.frames], video=True, quiet=True)


def _read_mask(path) -> np.ndarray:
    from geoface.images import read_image

    m = read_image(path)  # float in [0, 1]
    return (m if m.ndim == 2 else m[..., 0]) > 0.5


def _job(job) -> list:
    try:
        return _job_rows(job)
    except Exception as e:  # one broken run must not stop the others; say what broke
        import traceback

        return [{"stage": "error", "job": [str(x) for x in job[1:5]], "error": f"{type(e).__name__}: {e}",
                 "where": traceback.format_exc().splitlines()[-3:]}]


def _job_rows(job) -> list:
    import torch

    from geoface.hfm import ABLATIONS, HFMConfig, evaluate_hmd, load_hfm, train_hfm
    from geoface.hfm.data import load_video

    d, split, data_seed, seed, variant, iters, threads, device, models = job
    torch.set_num_threads(threads)
    ablation, poses = VARIANTS[variant]
    mdir = Path(models) / f"{split}_{data_seed}_{variant}_s{seed}"
    cfg = HFMConfig(**{**ABLATIONS[ablation], **PAPER.get(variant, {}), **OURS.get(variant, {}), "iters": iters, "seed": seed,
                       "threads": threads})
    info_file = mdir / "train_info.json"
    trained = not (info_file.is_file() and (mdir / "model.safetensors").is_file())
    if not trained:  # trained before: score it again
        info = json.loads(info_file.read_text())
    else:
        info = train_hfm(Path(d) / "registration", mdir, cfg, progress=False, log=None, poses=poses, device=device)
        info = {k: v for k, v in info.items() if k != "history"}
    model = load_hfm(mdir)
    if trained:
        if poses != "file":
            info.update(_registration_error(Path(d) / "registration", model, mdir))
        info_file.write_text(json.dumps(info))
    calibrated_after = False
    cal = model.pose_calibration
    if (cal is None or ("fit_weights" in cal) != cfg.pose_calibration_weighted) and cfg.pose_calibration and poses != "file":
        # trained before the calibration (or its weighting) existed: learn it now from the same
        # registration poses (fitted to the landmarks as training fitted them), as training does
        reg = _registration(Path(d) / "registration", model, mdir)
        calibrated_after = _recalibrate(model, reg, cfg.pose_calibration, cfg.pose_calibration_ridge,
                                        cfg.pose_calibration_weighted, usage_landmarks=cfg.usage_landmarks) is not None
    rows = []
    video = load_video(Path(d) / "usage")
    cal = model.pose_calibration
    every_usage = poses != "file" or variant in REGISTERED_WITH_FILE
    for usage_poses in (("landmarks", "landmarks_uncalibrated", "image", "file") if every_usage else ("file",)):
        if usage_poses == "landmarks_uncalibrated" and cal is None:
            continue
        model.pose_calibration = None if usage_poses == "landmarks_uncalibrated" else cal
        r = evaluate_hmd(model, video, poses=usage_poses.split("_")[0])
        rows.append({"stage": "score", "split": split, "data_seed": data_seed, "seed": seed, "variant": variant,
                     "usage_poses": usage_poses, "pose_calibration": len(cal["basis"]) if cal else 0,
                     "calibrated_after_training": calibrated_after,
                     "train_seconds": None if info.get("seconds") is None else round(info["seconds"], 1),
                     "pose_fit_rms_px": info.get("pose_fit_rms_px"), "n_gaussians": len(model.gaussians),
                     **{k: info[k] for k in ("registration_pose_deg", "registration_pose_mm") if k in info},
                     **{k: (round(float(v), 4) if isinstance(v, (int, float)) else v) for k, v in r.items()}})
    return rows


def _run(a) -> None:
    import multiprocessing as mp

    jobs = []
    models = a.models or str(Path(a.out) / "models")
    data = Path(a.data) if a.data else Path(a.out) / "data"
    # --group SPLIT/SEEDS/VARIANTS[/PEOPLE], in the order given (the first ones finish first), else
    # all of --splits × --seeds × --variants; PEOPLE defaults to --val or --test
    groups = [g.split("/") for g in a.group] if a.group else [[sp, ",".join(map(str, a.seeds)), ",".join(a.variants)]
                                                            for sp in a.splits]
    for split, seeds, variants, *people in groups:
        default = a.val if split == "val" else a.test
        for seed in (int(x) for x in seeds.split(",")):
            for s in ([int(x) for x in people[0].split(",")] if people else default):
                for v in variants.split(","):
                    d = _capture_dir(a.out, data, v) / f"{split}_{s}"
                    if not (d / "usage" / "meta.json").is_file():
                        raise SystemExit(f"{d}: no capture; run the data stage first"
                                         + (" and then the track stage" if v.startswith("tracked") else ""))
                    jobs.append((str(d), split, s, seed, v, a.iters, a.threads, a.device, models))
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from geoface.dataset import die_with_parent

    res = Path(a.out) / "results.jsonl"
    # the runs end with this driver (killed or interrupted), instead of training on for minutes; a run
    # killed on its own ends the driver and the other runs (BrokenProcessPool), instead of a wait forever
    with ProcessPoolExecutor(a.jobs, mp_context=mp.get_context("spawn"), initializer=die_with_parent,
                             initargs=(os.getpid(), False)) as pool, res.open("a") as f:
        try:
            for fut in as_completed([pool.submit(_job, j) for j in jobs]):
                for r in fut.result():
                    line = json.dumps(r)
                    print(line, flush=True)
                    f.write(line + "\n")
                    f.flush()
        except BrokenProcessPool:
            raise SystemExit(f"eval_hfm_ict: a run's process ended without its result (killed?); the rows so far are in {res}")


def _poses(a) -> None:
    from dataclasses import replace

    from geoface.mesh.io import load_mesh
    from geoface.avatar.head_pose import LOWER_RIGID_NAMES, poses_from_landmarks, solve_poses
    from geoface.hfm.data import load_video
    from geoface.hfm.train import registration_poses

    def errors(fit_R, fit_t, piv, video):
        rv, dt = _pose_offsets(video.poses, fit_R, fit_t, piv)
        ang, mm = np.linalg.norm(rv, axis=1), np.linalg.norm(dt, axis=1)
        return {"deg_mean": round(float(np.mean(ang)), 3), "deg_max": round(float(np.max(ang)), 3),
                "mm_mean": round(float(np.mean(mm)), 2), "mm_max": round(float(np.max(mm)), 2),
                "deg_centred": round(_centred_rms(rv), 3), "mm_centred": round(_centred_rms(dt), 2)}

    for split in a.splits:
        for s in (a.val if split == "val" else a.test):
            d = (Path(a.data) if a.data else Path(a.out) / "data") / f"{split}_{s}"
            reg, use = load_video(d / "registration", need_mesh=True), load_video(d / "usage")
            m = load_mesh(reg.mesh_path)
            fit = poses_from_landmarks(reg, m.V, m.F)
            names, P = fit["all_names"], fit["all_points3d"]
            sel = [n for n in use.names if n in LOWER_RIGID_NAMES and n in names]
            uf = solve_poses(use.camera, P[[names.index(n) for n in sel]],
                             use.landmarks[:, [use.names.index(n) for n in sel]], fit["pivot"])
            row = {"stage": "poses", "split": split, "data_seed": s,
                   "registration": {**errors(fit["R"], fit["t"], fit["pivot"], reg), "landmarks": len(fit["names"])},
                   "usage": {**errors(uf["R"], uf["t"], fit["pivot"], use), "landmarks": len(sel)}}
            for key in ("stable", "lower"):  # the other landmark sets of registration (HFMConfig.registration_landmarks)
                v = replace(reg, poses=None)
                info = registration_poses(v, "landmarks", mesh=m, fit=key)
                row[f"registration_{key}"] = {**errors(*v.poses[:2], v.poses[2], reg), "landmarks": info["pose_landmarks"]}
            print(json.dumps(row), flush=True)
            with (Path(a.out) / "results.jsonl").open("a") as f:
                f.write(json.dumps(row) + "\n")


def _registration(reg_dir, model, model_dir=None):
    """The registration video with the poses the model was trained in: those its folder saved
    (training corrected them), else fitted to the landmarks as training fits them."""
    from geoface.mesh.io import load_mesh
    from geoface.hfm.data import load_video
    from geoface.hfm.io import load_registration_poses
    from geoface.hfm.train import registration_poses

    reg = load_video(reg_dir, need_mesh=True)
    saved = load_registration_poses(model_dir, len(reg)) if model_dir is not None else None
    if saved is not None:
        reg.poses = saved
    else:
        registration_poses(reg, "landmarks", None, load_mesh(reg.mesh_path), fit=model.cfg.registration_landmarks)
    return reg


def _pose_offsets(true_poses, R, t, pivot):
    """Per frame, the rotation vector (degrees) and the translation (mm) from the true poses
    (R, t, pivot) to the poses ``R``, ``t``; translations compared at ``pivot`` (the same rigid
    motion moves it to the same place)."""
    from geoface.avatar.head_pose import repivot, rotation_vector

    Rt, tt, pt = true_poses
    rv = np.degrees([rotation_vector(Rt[f].T @ R[f]) for f in range(len(R))])
    return rv, 1000 * (np.asarray(t) - repivot(Rt, tt, pt, pivot))


def _centred_rms(x) -> float:
    """Root mean square over the frames about the mean offset (the frame an avatar learns)."""
    return float(np.sqrt(((x - x.mean(0)) ** 2).sum(1).mean()))


def _registration_error(reg_dir, model, model_dir) -> dict:
    """How far the registration poses a no-file model was fitted in are from the true ones
    (``head_poses.npz``), frame by frame about their mean offset (the frame the avatar learned):
    root-mean-square degrees and millimetres (at the pivot)."""
    from geoface.hfm.data import load_video

    reg = _registration(reg_dir, model, model_dir)
    R, t, p = reg.poses
    rv, dt = _pose_offsets(load_video(reg_dir).poses, R, t, p)
    return {"registration_pose_deg": round(_centred_rms(rv), 3), "registration_pose_mm": round(_centred_rms(dt), 3)}


def _recalibrate(model, reg, components: int, ridge: float, weighted: bool = False, expressions: int = 0,
                 usage_landmarks: str = "lower"):
    """Learn the model's usage pose calibration anew from ``reg`` with these settings (None: none learned)."""
    from dataclasses import replace

    from geoface.hfm.train import calibrate_usage_poses

    model.cfg = replace(model.cfg, pose_calibration=components, pose_calibration_ridge=ridge,
                        pose_calibration_weighted=weighted, pose_calibration_expressions=expressions,
                        usage_landmarks=usage_landmarks)
    return calibrate_usage_poses(model, reg, "landmarks")


def _calibration(a) -> None:
    """Score trained no-file models with the usage pose calibration of each ``--grid`` setting
    (components:ridge[:w][:s][:eN][:hR][:aN|:AN]; 0:0 = none; w: weighted; s: the stable lower landmarks; hR: usage poses corrected by the headset
    masks with expression-map ridge R; aN: then aligned with the image, N steps per frame, turning the head only, AN:
    also moving it), learned from the registration video as training learns it."""
    from dataclasses import replace

    import torch

    from geoface.hfm import evaluate_hmd, load_hfm
    from geoface.hfm.data import load_video
    from geoface.hfm.usage import expression_coverage, usage_poses

    torch.set_num_threads(a.threads)
    models = Path(a.models or Path(a.out) / "models")
    data = Path(a.data) if a.data else Path(a.out) / "data"
    for split, seeds, variants, *people in (g.split("/") for g in a.group):
        default = a.val if split == "val" else a.test
        for seed in (int(x) for x in seeds.split(",")):
            for s in ([int(x) for x in people[0].split(",")] if people else default):
                for v in variants.split(","):
                    d = _capture_dir(a.out, data, v) / f"{split}_{s}"
                    model = load_hfm(models / f"{split}_{s}_{v}_s{seed}")
                    reg = _registration(d / "registration", model, models / f"{split}_{s}_{v}_s{seed}")
                    use = load_video(d / "usage")
                    for g in a.grid:
                        k, ridge, *flags = g.split(":")
                        draws = int(next((f[1:] for f in flags if f.startswith("e")), 0))
                        hs = next((float(f[1:]) for f in flags if f.startswith("h")), None)
                        align = next((f for f in flags if f[:1] in "aA"), "a0")
                        _recalibrate(model, reg, int(k), float(ridge), weighted="w" in flags, expressions=draws,
                                     usage_landmarks="stable" if "s" in flags else "lower")
                        model.cfg = replace(model.cfg, headset_pose=hs is not None, headset_pose_ridge=hs or 0.0,
                                            pose_align=int(align[1:]), pose_align_translation=align[0] == "A")
                        pose, source = usage_poses(model, use, "landmarks")  # once: the alignment is slow
                        r = evaluate_hmd(model, replace(use, poses=pose), poses="file")
                        r.update(poses=source, **_upper_error(model, use, pose), **(expression_coverage(model, use) or {}))
                        row = {"stage": "calibration", "split": split, "data_seed": s, "seed": seed, "variant": v,
                               "components": int(k), "ridge": float(ridge), "weighted": "w" in flags, "expressions": draws,
                               "usage_landmarks": model.cfg.usage_landmarks,
                               "headset_ridge": hs, "align_steps": int(align[1:]), "align_translation": align[0] == "A",
                               "poses": r["poses"], "upper_px": r["upper_px"], "lower_px": r["lower_px"],
                               **{k: round(float(r[k]), 4) for k in ("psnr_face", "ssim_face", "psnr_occluded",
                                                                     "ssim_occluded", "psnr_expression", "psnr_occluded_interior",
                                                                     "psnr_occluded_outline")},
                               **{k: round(float(r[k]), 4) for k in ("expression_beyond", "expression_reach_median",
                                                                     "expression_reach_max") if k in r}}
                        print(json.dumps(row), flush=True)
                        with (Path(a.out) / "results.jsonl").open("a") as f:
                            f.write(json.dumps(row) + "\n")


def _upper_error(model, use, pose) -> dict:
    """How far the usage poses ``pose`` (fitted to the landmarks, as the model's settings say) put the head's
    upper (iBUG 17–47: brows, nose bridge, eyes) and lower landmarks from where the true poses put
    them: mean image distance, pixels."""
    from geoface.avatar.capture import IBUG68_NAMES
    from geoface.avatar.head_pose import repivot

    R, t, piv = pose
    Rt, tt, pt = use.poses
    tt = repivot(Rt, tt, pt, piv)
    known = dict(zip(model.landmarks3d["names"], np.asarray(model.landmarks3d["points"])))
    out = {}
    for key, names in (("upper_px", IBUG68_NAMES[17:48]), ("lower_px", IBUG68_NAMES[:17] + IBUG68_NAMES[48:])):
        X = np.array([known[n] for n in names if n in known]) - piv
        d = [np.linalg.norm(use.camera.project(X @ R[f].T + piv + t[f])[0] - use.camera.project(X @ Rt[f].T + piv + tt[f])[0],
                            axis=1).mean() for f in range(len(R))]
        out[key] = round(float(np.mean(d)), 4)
    return out


def _table(a) -> None:
    rows = [json.loads(x) for x in (Path(a.out) / "results.jsonl").read_text().splitlines() if '"score"' in x]
    keys = ("psnr_face", "ssim_face", "psnr_occluded", "ssim_occluded", "psnr_expression")
    for split in ("val", "test"):
        sel = [r for r in rows if r["split"] == split]
        if not sel:
            continue
        print(f"## {split}: {len({r['data_seed'] for r in sel})} people × {len({r['seed'] for r in sel})} model seeds")
        print("| variant | usage poses | n | " + " | ".join(keys) + " |")
        print("|---|---|---|" + "---|" * len(keys))
        for v in VARIANTS:
            for up in ("file", "landmarks", "landmarks_uncalibrated", "image"):
                g = [r for r in sel if r["variant"] == v and r["usage_poses"] == up]
                if g:
                    print(f"| {v} | {up} | {len(g)} | " + " | ".join(f"{np.mean([r[k] for r in g]):.3f}" for k in keys) + " |")
        base = {(r["data_seed"], r["seed"]): r for r in sel if r["variant"] == "full" and r["usage_poses"] == "landmarks"}
        for v, up in [("oracle", "file"), ("full", "landmarks_uncalibrated")] + [
                (v, "landmarks") for v in VARIANTS if v not in ("oracle", "full")]:
            pairs = [(base[k], r) for r in sel if r["variant"] == v and r["usage_poses"] == up
                     for k in [(r["data_seed"], r["seed"])] if k in base]
            if pairs:
                d = {k: [b[k] - o[k] for b, o in pairs] for k in ("psnr_face", "psnr_occluded")}
                print(f"full (no pose file) − {v} ({up}): " + ", ".join(
                    f"{k} {np.mean(x):+.2f} dB ({sum(y > 0 for y in x)} of {len(x)} better)" for k, x in d.items()))
        runs = {}  # (person, model seed) -> {(variant, usage poses): row}
        for r in sel:
            runs.setdefault((r["data_seed"], r["seed"]), {})[(r["variant"], r["usage_poses"])] = r

        def per_run(cols, a_key, b_key):  # person × model seed: "a / b" of each column
            print("\n| person | model seed | " + " | ".join(f"{v} ({up})" for v, up in cols) + " |")
            print("|---|---|" + "---|" * len(cols))
            for key, got in sorted(runs.items()):
                print(f"| {key[0]} | {key[1]} | " + " | ".join(
                    f"{got[c][a_key]:.2f} / {got[c][b_key]:.2f}" if b_key in got.get(c, {}) else "—" for c in cols) + " |")

        per_run([("oracle", "file"), ("full", "landmarks_uncalibrated")] + [(v, "landmarks") for v in MAIN[1:]],
                "psnr_face", "psnr_occluded")
        if any("psnr_occluded_outline" in r for r in sel):  # where in the occluded region the PSNR is lost
            print("\noccluded region, interior / outline (1 px inside the face's edge) PSNR")
            per_run([("oracle", "file"), ("full", "file")] + [(v, "landmarks") for v in MAIN[1:]], "psnr_occluded_interior",
                    "psnr_occluded_outline")


def main(argv=None) -> int:
    ints = lambda s: [int(x) for x in s.split(",") if x]  # noqa: E731
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stage", choices=("data", "track", "run", "poses", "calibration", "table", "head_track_usage"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--val", type=ints, default=[10])
    ap.add_argument("--test", type=ints, default=[11, 12, 13])
    ap.add_argument("--head-track", action="store_true",
                    help="track: also OUT/data_head_track, registered with the ICT head track's poses (variant tracked_head_track)")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--usage", type=int, default=50)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--rom", type=float, default=0.0,
                    help="data: seconds of range of motion that open each registration video (0: none)")
    ap.add_argument("--splits", type=lambda s: s.split(","), default=["test"])
    ap.add_argument("--seeds", type=ints, default=[0, 1])
    ap.add_argument("--variants", type=lambda s: s.split(","), default=MAIN,
                    help=f"comma-separated, of {list(VARIANTS)} (default: {','.join(MAIN)})")
    ap.add_argument("--iters", type=int, default=1500)
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--threads", type=int, default=1, help="torch threads per run")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--group", action="append", default=[], metavar="SPLIT/SEEDS/VARIANTS[/PEOPLE]",
                    help="run: jobs in this order, e.g. test/0/full,oracle or test/1/full/11,12 "
                         "(repeatable; instead of --splits/--seeds/--variants)")
    ap.add_argument("--models", default=None, help="run: where the models go (default OUT/models)")
    ap.add_argument("--data", default=None, help="where the captures are (default OUT/data)")
    ap.add_argument("--grid", type=lambda s: s.split(","), default="0:0,4:0.01,8:0.001,8:0.01,8:0.1,12:0.01,16:0.001,16:0.01,16:0.1,24:0.01",
                    help="calibration: COMPONENTS:RIDGE[:w][:s][:eN][:hR] settings of the usage pose calibration (0:0 = none; "
                         ":w = its poses weigh the landmarks by how little they moved; :s = usage poses fitted to the "
                         "8 stable lower landmarks; :eN = each registration "
                         "frame also seen N times with generic expressions; :hR = usage poses corrected by the "
                         "headset masks, expression-map ridge R)")
    a = ap.parse_args(argv)
    if any(len(g.split("/")) not in (3, 4) for g in a.group):
        ap.error("--group: SPLIT/SEEDS/VARIANTS[/PEOPLE], e.g. test/0,1/full,oracle")
    named = a.variants + [v for g in a.group for v in g.split("/")[2].split(",")]
    bad = [v for v in named if v not in VARIANTS]
    if bad:
        ap.error(f"unknown variants {bad}; choose from {list(VARIANTS)}")
    os.makedirs(a.out, exist_ok=True)
    {"data": _data, "track": _track, "run": _run, "poses": _poses, "calibration": _calibration, "table": _table,
     "head_track_usage": _usage_head_track}[a.stage](a)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
