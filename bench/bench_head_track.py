"""The ICT head track (``geoface.track.head_track``) where the truth is known: ICT-FaceKit people
rendered talking, as ``talk synth`` renders them (``geoface.avatar.ict``: lit skin, eyes, teeth;
speech-driven jaw and lips, emotions, blinks; head motion about the neck with camera shake),
tracked from their pixels alone (MediaPipe's face mesh in video mode → the fit). Beside it,
today's head poses: PnP with a robust loss on the 68 iBUG points MediaPipe gives
(``geoface.avatar.head_pose.solve_poses``) onto the person's *true* 68 landmark vertices and the
*true* camera (what ``talk train --fit-poses`` and HFM-GS's registration do) — an oracle head and
camera the track does without.

Per person and method, one JSON line: head rotation error (degrees, mean / p95 / max; the angle
of R_tracked R_trueᵀ in camera coordinates; and "aligned": after the clip's one constant rotation
between the fitted and the true head's own frames, which identity and pose trade and the avatar's
head mesh carries with it), translation error (mm, the face centre's —
the mean of the 68 landmark vertices — position in camera coordinates; then after the clip's one
depth scale; then its motion: after that scale and one offset fixed to the fitted head), expression weights'
correlation with the truth (Pearson over frames, averaged over the blendshapes that move more
than 0.05), vertex error of the tracked head against the true one (mm over the face's vertices,
mean and p95), and frames per second. Each fit twice: with the focal length estimated, and
known (the true one given). ``--refine``: also the photometric refinement after the landmark fit
with the focal length estimated (``refine_photometric``), with the photometric error before and after;
``--refine-focal known`` (or ``both``): the refinement of the fit given the true focal length, as
a user who knows the camera's (``geoface capture --focal``) gets. ``--fits``: only one of the two fits.

``--refine-unlit``: also the refinement as it was before the head's colours were lit and its
identity refined (``shading=False, identity=False``, blurred 2 then 1 px). ``--refine-coarse``: the
lit refinement with the blur it had before (2 then 1 px; the default now goes on to finer levels).

``--cache DIR``: each person's rendered clip, points and truth are kept there (an npz) and read
back on the next run (the renders take two minutes a person).

``--floor``: also the landmarks' own floor (:func:`rigid468`).

``--blur-choice "2,1;1,0.5,0.25,0;..."``: only the refinement, once per blur schedule, each row
with its ``blur`` (how the default schedule was chosen, on the validation people).

``--tilt-only``: only how far each person's identity tilts the head in the model's frame
(:func:`identity_tilt_deg`), one line each (nothing rendered or tracked).

Seeds: 11 and 12 validation (where the refinement's weights were chosen), 13, 14, 15 test.

    python bench/bench_head_track.py [--seeds 11 12 13 14 15] [--res 512] [--seconds 3] [--refine] [--refine-unlit]
        [--floor] [--cache DIR] [--out FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def render_person(seed: int, res: int, seconds: float, fps: float = 25.0):
    """Frames and the truth of one talking ICT person (the generator of ``talk synth``)."""
    from geoface.avatar.ict import ICTPerson, arkit_curves, head_motion
    from geoface.rotations import euler_rotation
    from geoface.avatar.audio import speech_like

    rng = np.random.default_rng([seed, 7201])
    person = ICTPerson(rng, res=res, supersample=2)
    T = int(seconds * fps)
    _, env, _ = speech_like(seconds, 16000, int(rng.integers(1 << 31)))
    at = np.clip(((np.arange(T) + 0.5) / fps * 16000).astype(int) - 640, 0, len(env) - 1)
    curves = arkit_curves(T, rng, fps=fps, loudness=env[at], emote=0.5)
    ang, tr = head_motion(T, rng, fps, 2.0, 1.0, 0)  # twice talk synth's motion: ±20° yaw, ±10° pitch
    frames, Vcam, Rcam = [], [], []
    cam = person.cam
    for k in range(T):
        R = euler_rotation(*ang[k])
        V, rgb, alpha, _ = person.render(curves[k], R, tr[k])
        frames.append(np.round(np.clip(rgb * (alpha[..., None] > 0.5), 0, 1) * 255).astype(np.uint8))
        Vcam.append(V @ cam.R.T + cam.t)
        Rcam.append(cam.R @ R)
    names = person.model.expression_names
    E = np.array([[c.get(n, 0.0) for n in names] for c in curves])
    return person, frames, np.stack(Vcam), np.stack(Rcam), E


def angle_deg(Ra, Rb):
    c = (np.einsum("tij,tij->t", Ra, Rb) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def identity_tilt_deg(person) -> float:
    """How far the person's identity turns the head in the model's own frame: the angle of the
    rotation that best lays the mean ICT head's skin on the person's (a similarity), degrees.
    The truth's head pose is given in this tilted frame; a fitted identity tilts it its own way."""
    from geoface.track.head_track import CM_TO_M, model_view

    from geoface.mesh.align import similarity_transform

    v = model_view()
    skin = v.labels <= 2
    Q = similarity_transform(v.neutral[skin].astype(np.float64) * CM_TO_M, person.V0[skin])[1]
    return float(np.degrees(np.arccos(np.clip((np.trace(Q) - 1) / 2, -1, 1))))


def scores(person, Vtrue, Rtrue, Etrue, Rfit, Vfit, Efit=None, neutral_fit=None):
    lm = person.rest.landmarks
    face = person.rest.labels == 0
    rot = angle_deg(Rfit, Rtrue)
    # the same after the clip's one constant rotation (the fitted head's own frame against the true
    # head's: a tilt that identity and pose trade, which the avatar's head mesh carries with it)
    from scipy.spatial.transform import Rotation

    off = Rotation.from_matrix(np.einsum("tij,tkj->tik", Rfit, Rtrue)).mean().as_matrix()
    rot_aligned = angle_deg(np.einsum("ji,tjk->tik", off, Rfit), Rtrue)
    # the head's motion: after the clip's one rotation between the fitted and the true head's own
    # frames (R_fit = R_true Q: the gauge the identity and the pose share — ICT's identity modes
    # tilt the head — and all the capture keeps, its poses being relative to frame 0)
    offh = Rotation.from_matrix(np.einsum("tji,tjk->tik", Rtrue, Rfit)).mean().as_matrix()
    rot_motion = angle_deg(Rfit @ offh.T, Rtrue)
    cf, ct = Vfit[:, lm].mean(1), Vtrue[:, lm].mean(1)
    ctr = np.linalg.norm(cf - ct, axis=1) * 1000
    # the face centre after the clip's one scale about the camera (a head s times bigger s times
    # further away projects the same: the depth one camera cannot tell)
    s = float((cf * ct).sum() / (cf * cf).sum())
    ctr_s = np.linalg.norm(s * cf - ct, axis=1) * 1000
    # the face centre's motion: after that one scale and one offset fixed to the fitted head (where
    # the face centre sits on a head of another shape: the gauge that the shape shares with the
    # pose, as the rotation's above, and which the capture's poses, relative to frame 0, drop):
    # ct_k ≈ s cf_k + R_fit,k u, least squares in (s, u)
    A = np.concatenate([cf.reshape(-1, 1), Rfit.reshape(-1, 3)], 1)
    su = np.linalg.lstsq(A, ct.reshape(-1), rcond=None)[0]
    ctr_m = np.linalg.norm(ct - su[0] * cf - Rfit @ su[1:], axis=1) * 1000
    out = {"rot_mean_deg": rot.mean(), "rot_p95_deg": np.percentile(rot, 95), "rot_max_deg": rot.max(),
           "rot_aligned_mean_deg": rot_aligned.mean(), "rot_aligned_p95_deg": np.percentile(rot_aligned, 95),
           "rot_motion_mean_deg": rot_motion.mean(), "rot_motion_p95_deg": np.percentile(rot_motion, 95),
           "trans_mean_mm": ctr.mean(), "trans_p95_mm": np.percentile(ctr, 95),
           "trans_scaled_mean_mm": ctr_s.mean(), "trans_scaled_p95_mm": np.percentile(ctr_s, 95), "scale": s,
           "trans_motion_mean_mm": ctr_m.mean(), "trans_motion_p95_mm": np.percentile(ctr_m, 95)}
    if Vfit.shape[1] == Vtrue.shape[1]:
        ve = np.linalg.norm(Vfit[:, face] - Vtrue[:, face], axis=-1) * 1000
        out.update(vertex_mean_mm=ve.mean(), vertex_p95_mm=np.percentile(ve, 95))
    if neutral_fit is not None:
        out["shape_mean_mm"], out["shape_p95_mm"] = person.face_shape_error_mm(neutral_fit)
    if Efit is not None:
        moving = Etrue.std(0) > 0.05
        cs = [np.corrcoef(Efit[:, j], Etrue[:, j])[0, 1] for j in np.flatnonzero(moving)]
        out.update(expr_corr=float(np.nanmean(cs)), expr_moving=int(moving.sum()))
    return {k: round(float(v), 4) if isinstance(v, float) else v for k, v in out.items()}


def track_scores(person, Vtrue, Rtrue, Etrue, track):
    """:func:`scores` of a fitted :class:`~geoface.track.head_track.HeadTrack`."""
    Vfit = np.stack([track.posed(k) for k in range(len(track))])
    return scores(person, Vtrue, Rtrue, Etrue, track.R, Vfit, track.expressions, track.neutral())


def pnp68(person, frames_pts68, Vtrue):
    """Today's poses: robust PnP of the true 68 landmark vertices (frame 0's canonical head) onto
    the tracked 68 points, through the true camera."""
    from geoface.avatar.head_pose import solve_poses

    V0 = person.V0  # canonical (rest) head, metres; the track poses it about the pivot
    L = V0[person.rest.landmarks]
    from geoface.avatar.head_pose import STABLE_NAMES  # noqa: F401  (the same rigid subset THGS uses)
    from geoface.landmarks import IBUG68_NAMES

    keep = [IBUG68_NAMES.index(n) for n in STABLE_NAMES]
    sol = solve_poses(person.cam, L[keep], frames_pts68[:, keep], person.pivot)
    Rw = sol["R"]
    Rcam = np.einsum("ij,tjk->tik", person.cam.R, Rw)
    Vw = np.einsum("tij,kj->tki", Rw, V0 - person.pivot) + person.pivot + sol["t"][:, None]
    return Rcam, Vw @ person.cam.R.T + person.cam.t


def rigid468(person, pts, Etrue):
    """The landmarks' own floor: the person's *true* identity and each frame's *true* expression
    weights at the table's 468 points (the view offsets included), posed by PnP on MediaPipe's
    points through the true camera — the best any fit of the ICT head to these points can do
    when shape and expression are exactly right; what is left is MediaPipe's own error."""
    from geoface.track.head_track import pnp, point_bases, view_offsets

    mean, Bid, Bex = point_bases()
    base = mean + np.tensordot(person.ident[: len(Bid)], Bid, axes=1)
    c = (person.cam.cx, person.cam.cy)
    Rs, Vs = [], []
    names = person.model.expression_names
    for k in range(len(pts)):
        X = base + np.einsum("e,ekd->kd", Etrue[k], Bex)
        ok = np.isfinite(pts[k]).all(1)
        r = pnp(X[ok], pts[k, ok], person.cam.fx, c)
        for _ in range(4):  # the offsets follow the view the pose gives
            Xo = X + view_offsets(r[0][None], r[1][None], mean.mean(0))[0]
            r = pnp(Xo[ok], pts[k, ok], person.cam.fx, c)
        Rs.append(r[0])
        Vs.append(person.shape(dict(zip(names, Etrue[k]))) @ r[0].T + r[1])
    return np.stack(Rs), np.stack(Vs)


def main(argv=None) -> int:
    from geoface.track import facemesh_points, ibug68_from_mediapipe
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import TrackSettings, fit_head_track

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[13, 14, 15])
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--refine", action="store_true", help="also the photometric refinement")
    ap.add_argument("--refine-focal", choices=("estimated", "known", "both"), default="estimated",
                    help="which of the two fits the refinements start from (default: the one with the focal length estimated)")
    ap.add_argument("--fits", choices=("estimated", "known", "both"), default="both",
                    help="the landmark fits made: focal length estimated, known, or both (default)")
    ap.add_argument("--refine-unlit", action="store_true",
                    help="also the refinement as it was: one colour per point, the identity kept (shading=False, identity=False)")
    ap.add_argument("--refine-coarse", action="store_true",
                    help="also the refinement with the coarse-to-fine blur it had before (2 and 1 px)")
    ap.add_argument("--blur-choice", default=None, metavar="S1;S2;...",
                    help="only the refinement (focal fitted), once per blur schedule (σ px, comma-separated; "
                         "schedules separated by ';'): the choice of the default on the validation people")
    ap.add_argument("--floor", action="store_true",
                    help="also the landmarks' floor: true identity, expressions and camera, posed by PnP")
    ap.add_argument("--settings", default="{}", help="TrackSettings overrides as JSON")
    ap.add_argument("--tilt-only", action="store_true", help="only how far each identity tilts the head")
    ap.add_argument("--cache", type=Path, default=None, help="keep the rendered clips here (npz) and reuse them")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    settings = TrackSettings(**json.loads(a.settings))

    from _results import emitter

    emit = emitter(a.out)
    if a.tilt_only:
        from geoface.avatar.ict import ICTPerson

        for seed in a.seeds:
            person = ICTPerson(np.random.default_rng([seed, 7201]), res=64, map_res=64, supersample=1)
            emit({"seed": seed, "split": "val" if seed in (11, 12) else "test", "method": "truth",
                  "identity_tilt_deg": round(identity_tilt_deg(person), 3)})
        return 0
    for seed in a.seeds:
        clip = None if a.cache is None else a.cache / f"ict{seed}_{a.res}_{a.seconds:g}s_truth.npz"
        if clip is not None and clip.exists():
            from geoface.avatar.ict import ICTPerson

            z = np.load(clip)
            person = ICTPerson(np.random.default_rng([seed, 7201]), res=a.res, supersample=2)
            frames, pts, Vtrue, Rtrue, Etrue = list(z["frames"]), z["pts"], z["Vtrue"], z["Rtrue"], z["Etrue"]
        else:
            person, frames, Vtrue, Rtrue, Etrue = render_person(seed, a.res, a.seconds)
            pts = facemesh_points(frames, video=True, quiet=True)
            if clip is not None:
                clip.parent.mkdir(parents=True, exist_ok=True)
                np.savez(clip, frames=np.stack(frames), pts=pts, Vtrue=Vtrue, Rtrue=Rtrue, Etrue=Etrue)
        split = "val" if seed in (11, 12) else "test"
        base = {"seed": seed, "split": split, "res": a.res, "frames": len(frames)}
        rgb = np.stack(frames).astype(np.float32) / 255.0
        masks = (rgb.max(-1) > 0).astype(np.float32)
        if a.blur_choice:
            tr = fit_head_track(pts, (a.res, a.res), settings=settings, quiet=True)
            for sched in a.blur_choice.split(";"):
                blur = tuple(float(x) for x in sched.split(","))
                t0 = time.perf_counter()
                tr2, ref = refine_photometric(tr, rgb, masks, pts, quiet=True, blur=blur)
                emit({**base, "method": "ict_head_track_refined", "focal": "estimated", "blur": list(blur),
                      **track_scores(person, Vtrue, Rtrue, Etrue, tr2),
                      "refine_seconds": round(time.perf_counter() - t0, 1),
                      "photo_err_after": round(float(np.nanmean(ref.after)), 4)})
            continue
        for focal in ("estimated", "known"):
            if a.fits not in (focal, "both"):
                continue
            t0 = time.perf_counter()
            tr = fit_head_track(pts, (a.res, a.res), focal=person.cam.fx if focal == "known" else None,
                                settings=settings, quiet=True)
            sec = time.perf_counter() - t0
            fits = [("ict_head_track", tr, sec, {})]
            variants = ([("ict_head_track_refined", {})] if a.refine else []) + (
                [("ict_head_track_refined_unlit", {"shading": False, "identity": False, "blur": (2.0, 1.0)})]
                if a.refine_unlit else []) + (
                [("ict_head_track_refined_coarse", {"blur": (2.0, 1.0)})] if a.refine_coarse else [])
            for name, kw in variants if a.refine_focal in (focal, "both") else []:
                t0 = time.perf_counter()
                tr2, ref = refine_photometric(tr, rgb, masks, pts, quiet=True, **kw)
                fits.append((name, tr2, sec + time.perf_counter() - t0,
                             {"photo_err_before": round(float(np.nanmean(ref.before)), 4),
                              "photo_err_after": round(float(np.nanmean(ref.after)), 4)}))
            for method, t_, s_, extra in fits:
                emit({**base, "method": method, "focal": focal, **track_scores(person, Vtrue, Rtrue, Etrue, t_),
                      "fps": round(len(frames) / s_, 2),
                      "focal_px": round(t_.focal, 1), "true_focal_px": round(person.cam.fx, 1),
                      "residual_px": round(float(np.nanmedian(t_.residual_px)), 3), **extra})
        idx, w = ibug68_from_mediapipe()
        p68 = np.einsum("tkjd,kj->tkd", pts[:, idx], w)
        Rp, Vp = pnp68(person, p68, Vtrue)
        emit({**base, "method": "pnp68_true_head_true_camera", "focal": "known",
              **scores(person, Vtrue, Rtrue, Etrue, Rp, Vp)})
        if a.floor:
            Rf, Vf = rigid468(person, pts, Etrue)
            emit({**base, "method": "rigid468_true_shape_true_camera", "focal": "known",
                  **scores(person, Vtrue, Rtrue, Etrue, Rf, Vf)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
