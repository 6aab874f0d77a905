"""Evaluation of THGS avatars: held-out PSNR/SSIM, the mouth, lip sync, and head poses.

* :func:`evaluate_thgs` — on the held-out frames (the last ``heldout`` fraction): PSNR/SSIM over
  the person, PSNR of the mouth rectangle, lip sync from the pixels (the rendered mouth's
  openness against the loudness) and, when the capture gives the lips' true gap
  (``meta.json``: ``lip_vertices``, ``lip_gap_m``), from the geometry (:func:`lip_gaps`);
  with ``poses_true.npz`` beside perturbed tracking, the head pose error of the training frames
  before and after the model's learned corrections (:func:`head_pose_errors`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from geoface.errors import AvatarError
from geoface.avatar.kinematics import joint_transforms
from geoface.thgs.model import THGSModel, lbs
from geoface.thgs.train import train_heldout_split
from geoface.thgs.inference import render_frames

__all__ = ["evaluate_thgs", "mouth_openness", "head_pose_errors", "corrected_poses", "lip_gaps", "lip_points",
           "true_lip_gaps_px"]


def _mouth_rect(model: THGSModel, camera, rot, transl, pad: int = 2, box=None):
    """Pixel rectangle (y0, y1, x0, x1) of the posed mouth box (or of ``box``, (2, 3) corners)."""
    lo, hi = model.template.mouth_box if box is None else np.asarray(box, np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    W = model.skin(torch.tensor(corners, dtype=torch.float32))
    A = joint_transforms(model.joints, model.parents, torch.as_tensor(rot, dtype=torch.float32),
                         torch.as_tensor(transl, dtype=torch.float32))
    P, _ = lbs(torch.tensor(corners, dtype=torch.float32), torch.tensor([[1.0, 0, 0, 0]]).repeat(8, 1), W, A)
    uv, _ = camera.project(P.detach().numpy().astype(np.float64))
    x0, y0 = np.floor(uv.min(0)).astype(int) - pad
    x1, y1 = np.ceil(uv.max(0)).astype(int) + pad
    H, Wd = camera.height, camera.width
    return max(y0, 0), min(y1, H), max(x0, 0), min(x1, Wd)


def mouth_openness(img, rect, thresh: float = 0.12) -> float:
    """Share of the mouth rectangle's pixels whose luma departs from the rectangle's median (the
    skin) by more than ``thresh``: the dark cavity and the teeth of an open mouth. On the
    synthetic talking head it correlates 0.95 with the true jaw opening."""
    y0, y1, x0, x1 = rect
    a = np.asarray(img)[y0:y1, x0:x1]
    if a.size == 0:
        return 0.0
    luma = a @ np.array([0.299, 0.587, 0.114])
    return float((np.abs(luma - np.median(luma)) > thresh).mean())


def head_pose_errors(template, rot, transl, true_rot, true_transl) -> dict:
    """Per-frame error of the head's rigid motion against the truth, whichever joints carry it:
    the transform of the template's head joint (the jaw's parent) from each pose — the angle
    between the rotations (degrees) and the distance (mm) the head's centre lands apart —
    mean, median and max over the frames; and the mean of the same about the frames' mean offset
    in the head's frame (``*_about_mean``: an avatar that learned itself shifted as a whole on
    the template is posed by poses shifted back, which it renders alike)."""
    from scipy.spatial.transform import Rotation

    joints = torch.tensor(template.joints)
    h = int(template.parents[template.jaw]) if template.jaw >= 0 else len(template.joints) - 1
    c = torch.tensor(template.V[template.head_mask].mean(0) if template.head_mask.any() else template.V.mean(0))
    ang, dist, rv, dc = [], [], [], []
    for r, t, r0, t0 in zip(rot, transl, true_rot, true_transl):
        A = joint_transforms(joints, template.parents, torch.as_tensor(r, dtype=torch.float64),
                             torch.as_tensor(t, dtype=torch.float64))[h]
        B = joint_transforms(joints, template.parents, torch.as_tensor(r0, dtype=torch.float64),
                             torch.as_tensor(t0, dtype=torch.float64))[h]
        d = A[:3, :3] @ c + A[:3, 3] - B[:3, :3] @ c - B[:3, 3]
        rv.append(Rotation.from_matrix((B[:3, :3].T @ A[:3, :3]).numpy()).as_rotvec())  # in the head's frame
        ang.append(float(np.linalg.norm(rv[-1])))  # the angle of A Bᵀ too (the same rotation, conjugated)
        dc.append((B[:3, :3].T @ d).numpy())
        dist.append(float(torch.linalg.norm(d)))
    ang, dist = np.degrees(ang), np.asarray(dist) * 1000
    rv, dc = np.asarray(rv), np.asarray(dc)
    return {"rot_deg_mean": float(ang.mean()), "rot_deg_median": float(np.median(ang)), "rot_deg_max": float(ang.max()),
            "mm_mean": float(dist.mean()), "mm_median": float(np.median(dist)), "mm_max": float(dist.max()),
            "rot_deg_about_mean": float(np.degrees(np.linalg.norm(rv - rv.mean(0), axis=1)).mean()),
            "mm_about_mean": float(1000 * np.linalg.norm(dc - dc.mean(0), axis=1).mean())}


def corrected_poses(model: THGSModel, rot, transl):
    """The training frames' poses with the model's learned per-frame corrections added."""
    n = min(len(rot), len(model.d_rot))
    r = np.array(rot, np.float64, copy=True)
    t = np.array(transl, np.float64, copy=True)
    r[:n] += model.d_rot.detach().double().numpy()[:n]
    t[:n] += model.d_transl.detach().double().numpy()[:n]
    return r, t


@torch.no_grad()
def lip_points(model: THGSModel, data, frames, lip_vertices) -> np.ndarray:
    """[T, 2, 3] per frame, the mean centres of the Gaussians bound to the two template vertices
    ``lip_vertices`` (upper and lower inner lip), posed by the frame's tracking and audio."""
    sel = model.gaussians_of(lip_vertices)
    A = model.audio_input(data.audio)
    out = []
    for t in frames:
        X = model(data.rot[t], data.transl[t], data.expr[t], A[t]).means
        out.append(torch.stack([X[sel[0]].mean(0), X[sel[1]].mean(0)]).numpy())
    return np.asarray(out, np.float64).reshape(-1, 2, 3)


def lip_gaps(model: THGSModel, data, frames, lip_vertices) -> np.ndarray:
    """Per frame, the distance (scene units) between the :func:`lip_points`: how far the avatar
    opens its mouth."""
    P = lip_points(model, data, frames, lip_vertices)
    return np.linalg.norm(P[:, 0] - P[:, 1], axis=-1)


def true_lip_gaps_px(data):
    """[T] the capture's own lip gap in the image (pixels): ``meta.json``'s ``lip_gap_px`` (the
    true inner-lip points projected), else the distance of the iBUG inner-lip landmarks 62 and 66
    of ``landmarks.json``; None when neither is there."""
    if "lip_gap_px" in data.meta:
        return np.asarray(data.meta["lip_gap_px"], np.float64)
    from geoface.avatar.capture import IBUG68_NAMES

    names = list(data.landmark_names or ())
    up, lo = (IBUG68_NAMES[i] for i in (62, 66))
    if data.landmarks is None or up not in names or lo not in names:
        return None
    return np.linalg.norm(data.landmarks[:, names.index(up)] - data.landmarks[:, names.index(lo)], axis=-1)


def evaluate_thgs(model: THGSModel, data, heldout: float | None = None) -> dict:
    """Held-out frames (the last ``heldout`` fraction): PSNR/SSIM over the person, PSNR of the mouth
    rectangle, and lip sync — the correlation of the rendered mouth's openness
    (:func:`mouth_openness`) with the audio loudness envelope, next to the same correlation for the real frames; FPS."""
    from geoface.avatar.audio import envelope, read_wav
    from geoface.splat.fit import psnr, ssim_masked

    h = model.cfg.heldout if heldout is None else heldout
    _, te = train_heldout_split(len(data), h)
    if len(te) < 2:
        raise AvatarError("evaluation needs at least two held-out frames")
    R, times = render_frames(model, data.camera, data.rot, data.transl, data.expr, data.audio, te)
    rows = {"psnr": [], "ssim": [], "psnr_mouth": []}
    lips = data.meta.get("lips_box")
    open_r, open_g = [], []
    for k, t in enumerate(te):
        gt = data.frames[t]
        m = gt.max(-1) > 0
        rows["psnr"].append(psnr(R[k], gt, m))
        rows["ssim"].append(ssim_masked(R[k], gt, m))
        rect = _mouth_rect(model, data.camera, data.rot[t], data.transl[t])
        # where the mouth opens, when the capture says (its mouth box also holds chin and cheeks)
        orect = rect if lips is None else _mouth_rect(model, data.camera, data.rot[t], data.transl[t], box=lips)
        y0, y1, x0, x1 = rect
        rows["psnr_mouth"].append(psnr(R[k][y0:y1, x0:x1], gt[y0:y1, x0:x1]))
        open_r.append(mouth_openness(R[k], orect))
        open_g.append(mouth_openness(gt, orect))
    out = {k: float(np.mean(v)) for k, v in rows.items()}
    wav = Path(data.meta.get("_folder", "")) / "audio.wav"
    if wav.is_file():
        x, sr = read_wav(wav)
        env = envelope(x, sr, data.fps, len(data))[te]
    else:  # loudness from the features: mean log-mel energy
        env = data.audio[te].mean(1)
    corr = lambda a, b: float(np.corrcoef(a, b)[0, 1]) if np.std(a) > 0 and np.std(b) > 0 else 0.0  # noqa: E731
    out.update(lipsync_corr=corr(open_r, env), lipsync_corr_real=corr(open_g, env),
               mouth_open_mae=float(np.mean(np.abs(np.asarray(open_r) - np.asarray(open_g)))),
               mouth_open_std=float(np.std(open_r)), mouth_open_std_real=float(np.std(open_g)),
               mouth_open_corr_real=corr(open_r, open_g),
               frames=len(te), fps=float(1 / np.median(times)))
    if "lip_vertices" in data.meta and "lip_gap_m" in data.meta:  # the mouth's opening, geometrically
        P = lip_points(model, data, te, data.meta["lip_vertices"])
        gap = np.linalg.norm(P[:, 0] - P[:, 1], axis=-1)
        true = np.asarray(data.meta["lip_gap_m"], np.float64)[te]
        out.update(lip_gap_corr_loudness=corr(gap, env), lip_gap_corr_loudness_real=corr(true, env),
                   lip_gap_corr_real=corr(gap, true), lip_gap_std_mm=float(np.std(gap) * 1000),
                   lip_gap_std_mm_real=float(np.std(true) * 1000))
        true_px = true_lip_gaps_px(data)
        if true_px is not None:  # … and as the camera sees it: the depth of an opening is not in the image
            uv = data.camera.project(P.reshape(-1, 3))[0].reshape(-1, 2, 2)
            px = np.linalg.norm(uv[:, 0] - uv[:, 1], axis=-1)
            out.update(lip_gap_px_std=float(np.std(px)), lip_gap_px_std_real=float(np.std(true_px[te])),
                       lip_gap_px_corr_real=corr(px, true_px[te]))
    truth = Path(data.meta.get("_folder", "")) / "poses_true.npz"
    if truth.is_file():  # a capture with perturbed tracking: how far the corrections took the poses
        tr, _ = train_heldout_split(len(data), h)
        with np.load(truth, allow_pickle=False) as z:
            r0, t0 = np.asarray(z["rot"])[tr], np.asarray(z["transl"])[tr]
        r1, t1 = corrected_poses(model, data.rot, data.transl)
        out["pose_before"] = head_pose_errors(model.template, data.rot[tr], data.transl[tr], r0, t0)
        out["pose_after"] = head_pose_errors(model.template, r1[tr], t1[tr], r0, t0)
    return out
