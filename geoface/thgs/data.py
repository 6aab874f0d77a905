"""Talking-avatar data for THGS: a folder format, a loader, and synthetic talking videos.

A data folder holds::

    frames/000000.png ...  RGB frames, background removed (black)
    camera.json            fixed camera (as in :mod:`geoface.hfm.data`)
    template.npz           the skinned template (:class:`geoface.avatar.template.Template`)
    poses.npz              per frame: rot [T, J, 3] local axis-angle joint rotations, transl [T, 3],
                           expr [T, K] expression coefficients (what a face/body tracker gives);
                           optional tracked_joints [J], tracked_expr [K] (bool; default all true):
                           what the tracker measured. Training corrects these per frame; the
                           others (e.g. a jaw and lips the tracker leaves to the audio) it never
                           corrects per frame, which would fit them frame by frame instead of
                           learning them from the audio
    audio.wav | features.npy   the speech (log-mel features are computed) or precomputed features
    meta.json              {"fps": 25, ...}
    landmarks.json         optional: a face tracker's 2D landmarks per frame, as in
                           :mod:`geoface.hfm.data` ({"names": [...], "points": [T][L][2]}
                           pixels; names may be left out for the 68 iBUG points). Training pulls
                           the template's vertices at the mouth's landmarks (the template's
                           ``landmark_names``/``landmark_vertices``) onto them: the jaw and lips
                           the tracker left to the audio then learn where the mouth is, not only
                           what colour it has

:func:`make_synthetic_talking` renders the procedural template talking: a speech-like signal
(voiced syllables of a pulse train through moving formant resonators, 3–6 syllables a second,
pauses) drives the jaw (opening with the loudness envelope, 40 ms behind the sound) and the lips
(rounding on "o"-like syllables); the head nods and turns slowly, the brows move. The tracker's
``poses.npz`` holds the head pose and the *non-mouth* expressions only — the jaw and lips are
left to be learned from the audio, so lip sync is what the audio module must learn and is
measurable (the mouth-opening ground truth is in meta.json).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.camera import Camera, look_at
from geoface.errors import AvatarError
from geoface.images import save_image
from geoface.avatar.capture import IBUG68_NAMES, camera_from_json, read_landmarks
from geoface.capture import Capture, write_camera
from geoface.errors import CaptureError
from geoface.avatar.template import Template
from geoface.avatar.audio import speech_like  # noqa: F401  (re-exported)

__all__ = ["TalkingData", "load_talking", "load_tracked", "make_synthetic_talking", "speech_like",
           "mouth_landmark_targets", "landmark_loss", "fit_head_poses"]


@dataclass
class TalkingData:
    frames: np.ndarray        # [T, H, W, 3] float32
    camera: Camera
    template: Template
    rot: np.ndarray           # [T, J, 3]
    transl: np.ndarray        # [T, 3]
    expr: np.ndarray          # [T, K]
    audio: np.ndarray         # [T, D] per-frame features
    fps: float
    meta: dict
    tracked_joints: np.ndarray  # [J] bool: rotations the tracker measured (:func:`load_tracked`)
    tracked_expr: np.ndarray    # [K] bool: expressions the tracker measured
    landmarks: np.ndarray | None = None  # [T, L, 2] pixels (landmarks.json), or None
    landmark_names: list | None = None

    def __len__(self):
        return len(self.frames)


def load_poses(path, n_joints: int, n_expr: int, n_frames: int | None = None):
    try:
        with np.load(path, allow_pickle=False) as d:
            rot, transl, expr = (np.asarray(d[k], np.float64) for k in ("rot", "transl", "expr"))
    except (OSError, KeyError, ValueError) as e:
        raise AvatarError(f"{path}: poses need rot [T, J, 3], transl [T, 3], expr [T, K] ({type(e).__name__}: {e})") from None
    T = len(rot)
    if rot.shape != (T, n_joints, 3) or transl.shape != (T, 3) or expr.shape != (T, n_expr):
        raise AvatarError(f"{path}: shapes rot {rot.shape}, transl {transl.shape}, expr {expr.shape} do not fit a "
                         f"template with {n_joints} joints and {n_expr} expressions")
    if n_frames is not None and T != n_frames:
        raise AvatarError(f"{path}: {T} poses for {n_frames} frames")
    if not (np.isfinite(rot).all() and np.isfinite(transl).all() and np.isfinite(expr).all()):
        raise AvatarError(f"{path}: non-finite poses")
    return rot, transl, expr


def load_tracked(path, n_joints: int, n_expr: int) -> tuple[np.ndarray, np.ndarray]:
    """(tracked_joints [J], tracked_expr [K]) bool masks of ``poses.npz`` (all true when absent)."""
    out = []
    with np.load(path, allow_pickle=False) as d:
        for key, n in (("tracked_joints", n_joints), ("tracked_expr", n_expr)):
            m = np.asarray(d[key]) if key in d.files else np.ones(n, bool)
            if m.shape != (n,) or m.dtype != bool:
                raise AvatarError(f"{path}: {key} must be a bool array of {n}; got {m.dtype} {m.shape}")
            out.append(m)
    return out[0], out[1]


def load_talking(folder) -> TalkingData:
    """Load a talking-capture folder (module doc; read through :class:`geoface.capture.Capture`);
    every problem is a one-line CaptureError."""
    from geoface.avatar.audio import audio_features

    cap = Capture(folder)
    cap.require("camera.json", "meta.json")
    cam = cap.camera()
    meta = cap.meta(need=True)
    try:
        fps = float(meta["fps"])
    except (ValueError, KeyError, TypeError) as e:
        raise CaptureError(f"{cap.path}/meta.json: needs fps ({type(e).__name__}: {e})") from None
    if cap.has("template.npz") or cap.has("poses.npz"):  # a synthetic capture: its own template and poses
        cap.require("template.npz", "poses.npz")
        tpl = Template.load(cap.path / "template.npz")
        rot, transl, expr = load_poses(cap.path / "poses.npz", len(tpl.joints), tpl.n_expr, len(cap))
        tracked = load_tracked(cap.path / "poses.npz", len(tpl.joints), tpl.n_expr)
    else:  # a real clip's capture: the tracked ICT head is the template, its track the poses
        from geoface.thgs.ict import capture_template

        tpl, rot, transl, expr, *tracked = capture_template(cap)
    src = cap.path / "features.npy" if cap.has("features.npy") else cap.audio()
    if src is None:
        raise CaptureError(f"{cap.path}: needs audio.wav or features.npy (a clip without sound: "
                           "`geoface capture --audio WAV` gives it one)")
    A = audio_features(src, len(cap), fps)
    imgs = cap.frames()
    meta["_folder"] = str(cap.path)
    lm = cap.landmarks() if cap.has("landmarks.json") else None
    return TalkingData(imgs, cam, tpl, rot, transl, expr, A, fps, meta, *tracked,
                       *((None, None) if lm is None else (lm.points, lm.names)))


def fit_head_poses(folder, *, names=None) -> dict:
    """Replace the head poses of the talking capture ``folder`` by poses fitted to its
    ``landmarks.json`` (a tracker's): each frame's rigid motion of the template (its rest shape,
    at the vertices the template names for the landmarks) that projects through ``camera.json``
    onto the landmarks ``names`` (default: :data:`geoface.avatar.head_pose.STABLE_NAMES`, those
    that expressions move least), by :func:`geoface.avatar.head_pose.solve_poses` (robust
    perspective-n-point from the previous frame's pose). The motion goes to the root joint
    (rotation about it and translation); the other joints and the expressions stay the
    capture's. The replaced poses are kept as ``poses_true.npz`` unless that exists (a renderer's
    truth). Returns ``{"frames", "names", "rms_px" (median reprojection error), "inliers" (median)}``."""
    from scipy.spatial.transform import Rotation

    from geoface.avatar.head_pose import STABLE_NAMES, solve_poses

    folder = Path(folder)
    for name in ("camera.json", "template.npz", "poses.npz", "landmarks.json"):
        if not (folder / name).is_file():
            raise AvatarError(f"{folder}: missing {name} (head poses are fitted to a tracker's landmarks.json)")
    tpl = Template.load(folder / "template.npz")
    cam = camera_from_json(folder / "camera.json")
    with np.load(folder / "poses.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    rot, transl = np.array(arrays["rot"], np.float64), np.array(arrays["transl"], np.float64)
    lm, lm_names = read_landmarks(folder / "landmarks.json", len(rot))
    names = [n for n in (STABLE_NAMES if names is None else names) if n in lm_names and n in tpl.landmark_names]
    if len(names) < 4:
        raise AvatarError(f"{folder}: only {len(names)} landmarks both in landmarks.json and on the template "
                         "(template landmark_names): cannot fit head poses (need 4)")
    P = tpl.V[[int(tpl.landmark_vertices[tpl.landmark_names.index(n)]) for n in names]]
    sol = solve_poses(cam, P, lm[:, [lm_names.index(n) for n in names]], tpl.joints[0])  # from the rest pose
    if not (folder / "poses_true.npz").is_file():
        np.savez(folder / "poses_true.npz", **arrays)
    rot[:, 0] = Rotation.from_matrix(sol["R"]).as_rotvec()
    arrays.update(rot=rot, transl=sol["t"])
    np.savez(folder / "poses.npz", **arrays)
    return {"frames": len(rot), "names": names, "rms_px": float(np.median(sol["rms_px"])),
            "inliers": float(np.median(sol["inliers"]))}


#: iBUG-68 names of the mouth's landmarks (points 48–67): what the landmark loss supervises
MOUTH_LANDMARKS = tuple(IBUG68_NAMES[48:68])


def mouth_landmark_targets(data: TalkingData):
    """(template vertices [M], pixels [T, M, 2]) of the mouth's landmarks that both the capture's
    ``landmarks.json`` and the template name, or None when there are none."""
    tpl = data.template
    if data.landmarks is None or not len(tpl.landmark_names):
        return None
    both = [n for n in MOUTH_LANDMARKS if n in data.landmark_names and n in tpl.landmark_names]
    if not both:
        return None
    verts = np.array([tpl.landmark_vertices[tpl.landmark_names.index(n)] for n in both])
    return verts, data.landmarks[:, [data.landmark_names.index(n) for n in both]]


def landmark_loss(means, camera, points, delta: float = 1.0):
    """Mean robust (pseudo-Huber, ``delta`` px) distance in image widths between the projections of
    ``means`` [M, 3] (torch, world) and the landmarks ``points`` [M, 2] (pixels)."""
    import torch

    d = camera.project(means)[0] - torch.as_tensor(points, dtype=means.dtype, device=means.device)
    return ((d.pow(2).sum(-1) + delta**2).sqrt() - delta).mean() / camera.width


def make_synthetic_talking(out, *, seconds: float = 8.0, fps: float = 25.0, res: int = 128, n_vertices: int = 6000,
                           seed: int = 0, supersample: int = 2, quiet: bool | None = None) -> Path:
    """Write a synthetic talking-head data folder (module doc); returns its path."""
    from scipy.io import wavfile

    from geoface.progress import progress
    from geoface.nn.mesh_render import render_mesh
    from geoface.avatar.template import procedural_template
    from geoface.synth.head import EXPRESSION_NAMES, head_model
    import torch

    from geoface.avatar.kinematics import joint_transforms

    out = Path(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    tpl = procedural_template(n_vertices, seed)
    model = head_model(n_vertices, seed)
    sr = 16000
    x, env, rnd = speech_like(seconds, sr, seed)
    wavfile.write(str(out / "audio.wav"), sr, (x * 32767).astype(np.int16))
    T = int(seconds * fps)
    lag = int(0.04 * sr)
    fr = lambda a: np.array([a[min(max(int((k + 0.5) / fps * sr) - lag, 0), len(a) - 1)] for k in range(T)])  # noqa: E731
    jaw_open = np.clip(fr(env) * 1.1, 0, 1)
    pucker = np.clip(fr(rnd), 0, 1)
    rng = np.random.default_rng(seed + 1)
    tt = np.arange(T) / fps
    ph = rng.uniform(0, 2 * np.pi, 6)
    J, K = len(tpl.joints), tpl.n_expr
    rot = np.zeros((T, J, 3))
    rot[:, 2, 0] = 0.06 * np.sin(2 * np.pi * 0.3 * tt + ph[0])   # head nod
    rot[:, 2, 1] = 0.10 * np.sin(2 * np.pi * 0.2 * tt + ph[1])   # head turn
    rot[:, 1, 2] = 0.03 * np.sin(2 * np.pi * 0.25 * tt + ph[2])  # neck tilt
    names = [n for n in EXPRESSION_NAMES if n != "jaw_open"]
    expr = np.zeros((T, K))
    expr[:, names.index("brow_raise")] = np.clip(np.sin(2 * np.pi * 0.15 * tt + ph[3]), 0, 1) * 0.8
    expr[:, names.index("smile")] = np.clip(np.sin(2 * np.pi * 0.11 * tt + ph[4]), 0, 1) * 0.5
    transl = np.zeros((T, 3))
    lm = tpl.V
    tgt = np.array([0.0, float(lm[:, 1].max() + lm[:, 1].min()) / 2 + 0.02, 0.0])
    cam = look_at(tgt + [0, 0, 0.62], tgt, width=res, height=res, fov_y_deg=30.0)
    joints = torch.tensor(tpl.joints)
    Wv = torch.tensor(tpl.weights)
    mouth_open_px = []
    for k in progress(range(T), "rendering talking video", total=T, quiet=quiet):
        e = {n: float(expr[k, i]) for i, n in enumerate(names)}
        e["jaw_open"] = float(jaw_open[k])
        e["pucker"] = float(pucker[k]) * 0.8
        head = model.mesh(e)
        # the tracker's pose only: LBS of the expressive mesh with the head pose
        A = joint_transforms(joints, tpl.parents, torch.tensor(rot[k]), torch.tensor(transl[k]))
        M = torch.einsum("nj,jab->nab", Wv, A).numpy()
        V = (M[:, :3, :3] @ head.V[..., None])[..., 0] + M[:, :3, 3]
        r = render_mesh(V, head.F, cam, head.colors, supersample=supersample)
        save_image(out / "frames" / f"{k:06d}.png", r.rgb * r.alpha[..., None])
        mouth_open_px.append(float(jaw_open[k]))
    # the tracker measures neither the jaw nor the lips' pucker: the audio's
    np.savez(out / "poses.npz", rot=rot, transl=transl, expr=expr, tracked_joints=np.arange(J) != tpl.jaw,
             tracked_expr=np.array([n != "pucker" for n in names]))
    tpl.save(out / "template.npz")
    write_camera(out, cam)
    (out / "meta.json").write_text(json.dumps({"fps": fps, "source": "procedural template", "seed": seed,
                                               "jaw_open": jaw_open.tolist(), "pucker": pucker.tolist(),
                                               "envelope": fr(env).tolist()}))
    return out
