"""THGS on real heads: a skinned template from the ICT-FaceKit model and lit talking captures.

* :func:`ict_template` — a person of the ICT-FaceKit model (built from scans of real people) as a
  :class:`~geoface.avatar.template.Template`: the rest head with eyes, teeth, gums, tongue and the
  mouth's interior, decimated; joints root (the neck pivot), neck, head, jaw and the two eyes;
  the jaw's hinge and skinning weights *fitted to the model's own jawOpen blendshape* (a rigid
  rotation fitted to the vertices that move most, its fixed axis the hinge; each vertex's weight
  the share of that rotation that explains its motion); the expression basis the model's other
  52 ARKit blendshapes (jaw opening is the jaw joint's job).
* :func:`make_ict_talking` — a talking-capture folder (:mod:`geoface.thgs.data` format) of
  one such person: a speech-like WAV whose loudness drives jaw and lips
  (:func:`geoface.avatar.ict.arkit_curves` with ``loudness``), emotions and blinks, lit skin
  with regions, eyes and teeth, rigid head motion about the neck and camera shake.  As a face
  tracker would, ``poses.npz`` holds the head pose and the expressions of the upper face and
  cheeks (brows, eyes, cheeks, nose); the mouth (``jaw*``, ``mouth*``) is left to the audio.
  With ``perturb=(degrees, mm)`` the tracked head pose of every frame is off by that much (a
  random axis and direction per frame) — the truth is in ``poses_true.npz`` — so that the joint
  optimisation of pose corrections can be measured (:func:`geoface.thgs.eval.head_pose_errors`).
  ``meta.json`` holds each frame's true gap between the inner lips' middles, in metres
  (``lip_gap_m``) and as the camera sees it, in pixels (``lip_gap_px``).

Units are metres.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from geoface.errors import AvatarError
from geoface.images import save_image
from geoface.avatar.capture import IBUG68_NAMES
from geoface.capture import write_camera, write_landmarks

__all__ = ["ict_template", "capture_template", "make_ict_talking", "perturb_capture", "is_mouth_blendshape", "JOINT_NAMES"]

JOINT_NAMES = ("root", "neck", "head", "jaw", "eye_L", "eye_R")
_PARENTS = (-1, 0, 1, 2, 2, 2)
_EYEBALL = 7  # region number of the eyeballs (geoface.synth.ict.REGIONS order)


def is_mouth_blendshape(name: str) -> bool:
    """Blendshapes of the mouth and jaw: what the audio, not the tracker, drives."""
    return name.startswith(("jaw", "mouth"))


def _rigid_fit(P: np.ndarray, Q: np.ndarray, w: np.ndarray):
    """Weighted least-squares rotation R and translation t with Q ≈ P Rᵀ + t (Kabsch, scipy's)."""
    from scipy.spatial.transform import Rotation

    w = w / w.sum()
    cp, cq = w @ P, w @ Q
    R = Rotation.align_vectors(Q - cq, P - cp, weights=w)[0].as_matrix()
    return R, cq - R @ cp


def _hinge(V: np.ndarray, D: np.ndarray):
    """The jaw's hinge from its blendshape ``D`` on ``V``: (rotation vector of the opening,
    a point on the axis, per-vertex weight in [0, 1])."""
    from scipy.spatial.transform import Rotation

    mag = np.linalg.norm(D, axis=1)
    moving = mag > 0.5 * mag.max()
    R, t = _rigid_fit(V[moving], V[moving] + D[moving], mag[moving])
    rv = Rotation.from_matrix(R).as_rotvec()
    axis = rv / max(np.linalg.norm(rv), 1e-12)
    # the fixed points: (I − R) c = t, solved in the plane across the axis (c · axis = 0 there),
    # then moved along the axis to the face's mid-plane (x = 0)
    A = np.vstack([np.eye(3) - R, axis[None]])
    c = np.linalg.lstsq(A, np.r_[t, 0.0], rcond=None)[0]
    if abs(axis[0]) > 1e-6:
        c = c - axis * (c[0] / axis[0])
    full = V @ R.T + t - V  # where the whole jaw would take each vertex
    w = (D * full).sum(1) / np.maximum((full * full).sum(1), 1e-18)
    w = np.where(np.linalg.norm(full, axis=1) > 1e-9, w, 0.0)
    return rv, c, np.clip(w, 0.0, 1.0)


def _sphere_centre(P: np.ndarray) -> np.ndarray:
    """Centre of the least-squares sphere through ``P`` (|p|² = 2 c·p + k, linear in c and k)."""
    A = np.c_[2 * P, np.ones(len(P))]
    return np.linalg.lstsq(A, (P * P).sum(1), rcond=None)[0][:3]


def _snap_landmarks(V: np.ndarray, L: np.ndarray) -> np.ndarray:
    """Move, for each landmark of ``L`` [68, 3] in turn, the nearest template vertex of ``V`` not
    taken by an earlier one onto it (in place; a few millimetres on a 6000-vertex head); returns
    their indices [68]."""
    from scipy.spatial import cKDTree

    _, cand = cKDTree(V).query(L, k=8)
    taken, out = set(), []
    for i, row in enumerate(cand):
        j = int(next(c for c in row if int(c) not in taken))
        taken.add(j)
        out.append(j)
        V[j] = L[i]
    return np.asarray(out, np.int64)


def ict_template(person, n_vertices: int = 6000):
    """The :class:`~geoface.avatar.ict.ICTPerson` ``person`` as a skinned THGS template
    (module doc).  Returns ``(template, info)``; ``info`` holds ``jaw_rotvec`` (the rotation of a
    full jawOpen, radians) and ``expression_names`` (the basis's order)."""
    from scipy.spatial import cKDTree

    from geoface.avatar.ict import CM_TO_M, ICT_PARTS
    from geoface.avatar.template import Template, smoothstep as _smoothstep

    model, rest = person.model, person.rest
    V0 = person.V0
    names = [n for n in model.expression_names if n != "jawOpen"]
    view = model.view(ICT_PARTS)
    E = {n: view.expression_modes[model.expression_names.index(n)].astype(np.float64) * CM_TO_M
         for n in model.expression_names}
    rv, hinge, w_jaw_full = _hinge(V0, E["jawOpen"])
    V, F, _ = person.init_mesh(n_vertices)
    lmk_v = _snap_landmarks(V, V0[rest.landmarks])  # template vertices at the 68 landmarks, exactly
    _, near = cKDTree(V0).query(V)
    lab = rest.labels[near]
    L0 = V0[rest.landmarks]
    chin_y = float(L0[8, 1])
    y = V[:, 1]
    pivot = person.pivot
    w_head = _smoothstep((y - (chin_y - 0.035)) / 0.05)
    w_neck = _smoothstep((y - (pivot[1] - 0.03)) / 0.04)
    eye = lab == _EYEBALL
    w_jaw = np.where(eye, 0.0, w_jaw_full[near]) * w_head
    W = np.zeros((len(V), len(JOINT_NAMES)))
    W[:, 4] = eye & (V[:, 0] > 0)
    W[:, 5] = eye & (V[:, 0] <= 0)
    rest_w = 1.0 - W[:, 4] - W[:, 5]
    W[:, 3] = w_jaw * rest_w
    W[:, 2] = (w_head - w_jaw) * rest_w
    W[:, 1] = (1 - w_head) * w_neck * rest_w
    W[:, 0] = (1 - w_head) * (1 - w_neck) * rest_w
    W = np.clip(W, 0, None)
    W /= W.sum(1, keepdims=True)
    ball = rest.labels == _EYEBALL
    eyes = [_sphere_centre(V0[ball & side]) for side in (V0[:, 0] > 0, V0[:, 0] <= 0)]
    # the root is the pivot the captures turn the head about
    joints = np.array([pivot, pivot + [0.0, 0.02, 0.0], [0.0, chin_y + 0.01, pivot[2]], hinge, *eyes])
    basis = np.stack([E[n][near] for n in names])
    lips = L0[48:68]
    lo, hi = lips.min(0), lips.max(0)
    lo = lo - [0.006, 0.006 + 0.02, 0.03]  # the opening jaw takes the lower lip down; teeth lie behind
    hi = hi + [0.006, 0.006, 0.006]
    tpl = Template(V, F, joints, np.array(_PARENTS), W, basis, w_head > 0.5, np.stack([lo, hi]),
                   list(JOINT_NAMES), jaw=3, landmark_names=list(IBUG68_NAMES), landmark_vertices=lmk_v)
    return tpl, {"jaw_rotvec": rv.tolist(), "expression_names": names}


def capture_template(cap, n_vertices: int = 6000):
    """The THGS inputs of a capture that ``geoface capture`` made from a real clip (a tracked ICT
    head: ``meta.json``'s ``ict_identity``, ``expressions.npz``, ``head_poses.npz``): the person's
    ICT identity as a skinned template (:func:`ict_template`) and, per frame, the tracked head pose
    as the root joint's rotation and translation and the tracked expressions of the upper face
    and cheeks; the mouth is left to the audio, as in :func:`make_ict_talking`. Returns
    ``(template, rot [T, J, 3], transl [T, 3], expr [T, K], tracked_joints [J], tracked_expr [K])``."""
    from scipy.spatial.transform import Rotation

    from geoface.avatar.ict import ICTPerson
    from geoface.errors import CaptureError

    meta = cap.meta(need=True)
    ex, poses = cap.expressions(), cap.head_poses()
    if "ict_identity" not in meta or ex is None or poses is None:
        raise CaptureError(f"{cap.path}: a talking capture needs template.npz and poses.npz, or the tracked ICT head "
                           "that `geoface capture` writes (meta.json's ict_identity, expressions.npz, head_poses.npz)")
    ident = np.asarray(meta["ict_identity"], np.float64)
    person = ICTPerson(np.random.default_rng(0), identity=ident, res=64, map_res=64, supersample=1)
    R, t, piv = poses
    if np.abs(piv - person.pivot).max() > 1e-4:
        raise CaptureError(f"{cap.path}/head_poses.npz: its pivot {np.round(piv, 4).tolist()} is not the tracked "
                           f"head's neck {np.round(person.pivot, 4).tolist()}")
    tpl, info = ict_template(person, n_vertices)
    names = info["expression_names"]
    W, wn = ex
    T = len(R)
    rot = np.zeros((T, len(JOINT_NAMES), 3))
    rot[:, 0] = Rotation.from_matrix(R).as_rotvec()
    expr = np.zeros((T, len(names)))
    for j, n in enumerate(names):
        if n in wn and not is_mouth_blendshape(n):
            expr[:, j] = W[:, wn.index(n)]
    d = tracked_dofs(names)
    return tpl, rot, np.asarray(t, np.float64), expr, d["tracked_joints"], d["tracked_expr"]


def lips_box(person) -> np.ndarray:
    """(2, 3) min/max corners, canonical metres, of where the mouth opens: the inner lips, 2 mm
    to the sides, 3 mm above, and 18 mm below (the lower lip of an open jaw); what
    :func:`geoface.thgs.eval.mouth_openness` looks at."""
    L = person.V0[person.rest.landmarks][60:68]
    lo, hi = L.min(0), L.max(0)
    return np.stack([lo - [0.002, 0.018, 0.02], hi + [0.002, 0.003, 0.005]])


#: pixels of Gaussian noise on the synthetic captures' 2D landmarks (a detector's error)
LANDMARK_NOISE_PX = 0.5

#: iBUG points of the inner lips' middles (upper, lower): their distance is the mouth's opening
LIP_POINTS = (62, 66)


def lip_vertices(template) -> list:
    """The template vertices at the inner lips' middles (:data:`LIP_POINTS`; :func:`ict_template`
    puts a vertex at each landmark)."""
    return [int(template.landmark_vertices[i]) for i in LIP_POINTS]


def tracked_dofs(names) -> dict:
    """What the synthetic tracker measures (``poses.npz``'s masks, :mod:`geoface.thgs.data`):
    the rigid head pose (the root joint; neck, head and eye joints stay at rest, the gaze is in
    the blendshapes) and the expressions that are not the mouth's."""
    return {"tracked_joints": np.array([n == "root" for n in JOINT_NAMES]),
            "tracked_expr": np.array([not is_mouth_blendshape(n) for n in names])}


def _unit_rows(rng, n: int) -> np.ndarray:
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _perturbed(rot, transl, deg: float, mm: float, rng):
    """Root rotations turned by ``deg`` about a random axis and translations moved ``mm`` in a
    random direction, each frame its own."""
    from scipy.spatial.transform import Rotation

    rot, transl = np.array(rot, np.float64, copy=True), np.array(transl, np.float64, copy=True)
    if deg or mm:
        dR = Rotation.from_rotvec(_unit_rows(rng, len(rot)) * np.radians(deg))
        rot[:, 0] = (dR * Rotation.from_rotvec(rot[:, 0])).as_rotvec()
        transl = transl + _unit_rows(rng, len(rot)) * mm / 1000.0
    return rot, transl


def perturb_capture(src, dst, perturb: tuple, seed: int = 0) -> Path:
    """Copy the talking capture ``src`` (with its ``poses_true.npz``) to ``dst`` with each frame's
    tracked head pose off by ``perturb`` = (degrees, millimetres) — the tracking errors a real
    tracker makes, for measuring the joint pose optimisation without rendering again."""
    import shutil

    src, dst = Path(src), Path(dst)
    truth = src / "poses_true.npz"
    if not truth.is_file():
        raise AvatarError(f"{src}: no poses_true.npz (a capture from make_ict_talking)")
    deg, mm = (float(x) for x in perturb)
    if not (deg >= 0 and mm >= 0):
        raise AvatarError(f"perturbations must be >= 0; got {perturb}")
    tmp = dst.with_name(f".{dst.name}.tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    from .._io import copy_checked

    copy_checked(src, tmp)
    with np.load(truth, allow_pickle=False) as z:
        rot, transl, expr = z["rot"], z["transl"], z["expr"]
    rot, transl = _perturbed(rot, transl, deg, mm, np.random.default_rng([seed, 7202]))
    with np.load(src / "poses.npz", allow_pickle=False) as z:  # what the tracker measured stays so
        tracked = {k: z[k] for k in ("tracked_joints", "tracked_expr") if k in z.files}
    np.savez(tmp / "poses.npz", rot=rot, transl=transl, expr=expr, **tracked)
    meta = json.loads((tmp / "meta.json").read_text())
    meta["perturb_deg_mm"] = [deg, mm]
    (tmp / "meta.json").write_text(json.dumps(meta))
    tmp.rename(dst)
    return dst


def make_ict_talking(out, *, seconds: float = 8.0, fps: float = 25.0, res: int = 128, identity=None, seed: int = 0,
                     n_vertices: int = 6000, map_res: int = 512, supersample: int = 2, emote: float = 0.5,
                     perturb: tuple = (0.0, 0.0), quiet: bool | None = None) -> Path:
    """Write a talking-capture folder of one ICT-FaceKit person (module doc); returns its path.

    ``perturb``: (degrees, millimetres) by which each frame's tracked head pose is off."""
    from scipy.io import wavfile
    from scipy.spatial.transform import Rotation

    from geoface.progress import progress
    from geoface.avatar.capture import euler_rotation
    from geoface.avatar.ict import ICTPerson, head_motion, arkit_curves
    from geoface.avatar.audio import speech_like

    deg, mm = (float(x) for x in perturb)
    if seconds * fps < 5 or not (deg >= 0 and mm >= 0):
        raise AvatarError(f"need at least 5 frames and perturbations >= 0; got {seconds} s at {fps} fps, {perturb}")
    out = Path(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([seed, 7201])
    person = ICTPerson(rng, identity=identity, res=res, map_res=map_res, supersample=supersample)
    tpl, info = ict_template(person, n_vertices)
    sr = 16000
    x, env, _ = speech_like(seconds, sr, int(rng.integers(1 << 31)))
    wavfile.write(str(out / "audio.wav"), sr, (x * 32767).astype(np.int16))
    T = int(seconds * fps)
    lag = int(0.04 * sr)  # the mouth follows the sound by 40 ms
    at = np.clip(((np.arange(T) + 0.5) / fps * sr).astype(int) - lag, 0, len(env) - 1)
    loud = env[at]
    curves = arkit_curves(T, rng, fps=fps, loudness=loud, emote=emote)
    ang, tr = head_motion(T, rng, fps, 1.0, 1.0, 0)
    names = info["expression_names"]
    J = len(JOINT_NAMES)
    rot = np.zeros((T, J, 3))
    transl = np.zeros((T, 3))
    expr = np.zeros((T, len(names)))
    jaw, gap, gap_px, marks = [], [], [], []
    lips = person.rest.landmarks[list(LIP_POINTS)]
    noise = np.random.default_rng([seed, 7203])
    for k in progress(range(T), "rendering ICT talking video", total=T, quiet=quiet):
        R = euler_rotation(*ang[k])
        V, rgb, alpha, _ = person.render(curves[k], R, tr[k])
        gap.append(float(np.linalg.norm(np.subtract(*V[lips]))))  # the true lip gap (a rigid motion keeps it)
        gap_px.append(float(np.linalg.norm(np.subtract(*person.cam.project(V[lips])[0]))))  # … as the camera sees it
        uv = person.cam.project(V[person.rest.landmarks])[0] + noise.normal(0, LANDMARK_NOISE_PX, (68, 2))
        marks.append(np.round(uv, 3).tolist())  # what a face tracker's landmark detector gives
        save_image(out / "frames" / f"{k:06d}.png", rgb * (alpha[..., None] > 0.5))
        rot[k, 0] = Rotation.from_matrix(R).as_rotvec()  # rigid about the root = the neck pivot
        transl[k] = tr[k]
        expr[k] = [0.0 if is_mouth_blendshape(n) else curves[k].get(n, 0.0) for n in names]
        jaw.append(curves[k].get("jawOpen", 0.0))
    np.savez(out / "poses_true.npz", rot=rot, transl=transl, expr=expr)
    write_landmarks(out, marks, IBUG68_NAMES)
    rot, transl = _perturbed(rot, transl, deg, mm, np.random.default_rng([seed, 7202]))
    np.savez(out / "poses.npz", rot=rot, transl=transl, expr=expr, **tracked_dofs(names))
    tpl.save(out / "template.npz")
    write_camera(out, person.cam)
    (out / "meta.json").write_text(json.dumps({
        "fps": fps, "source": "ICT-FaceKit", "seed": seed, "identity": [round(float(v), 5) for v in person.ident],
        "expression_names": names, "tracked_expressions": [n for n in names if not is_mouth_blendshape(n)],
        "jaw_open": [round(float(v), 5) for v in jaw], "envelope": [round(float(v), 5) for v in loud],
        "jaw_rotvec": info["jaw_rotvec"], "perturb_deg_mm": [deg, mm], "lips_box": lips_box(person).tolist(),
        "lights": [a.tolist() for a in person.lights], "lip_vertices": lip_vertices(tpl),
        "lip_gap_m": [round(g, 6) for g in gap], "lip_gap_px": [round(g, 4) for g in gap_px]}))
    return out
