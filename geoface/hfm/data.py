"""Videos for HFM-GS (HMD removal): a folder format, a loader, and a synthetic generator.

A video folder (registration or usage) holds::

    frames/000000.png ...   RGB frames, background removed (black)
    masks/000000.png ...    optional foreground masks (nonzero = person); default: frame != 0
    landmarks.json          {"names": [...], "points": [[[x, y], ...] per frame]} in pixels;
                            without "names", 68 points per frame are the iBUG 68 (IBUG68_NAMES);
                            the lower-face crop uses nose_tip, mouth_left, mouth_right, chin
    camera.json             {"fx", "fy", "cx", "cy", "width", "height", "R", "t"} (OpenCV, world→camera)
    meta.json               {"y_split": y_t in world metres, "up": [0, 1, 0]}: the upper/lower split
    head.ply | head.obj     a head mesh with vertex colours, in the canonical (first-frame) pose:
                            initialises the canonical Gaussians (registration folders)
    hmd_masks/000000.png    usage folders: pixels hidden by the headset (what the user has:
                            segmented from the frames, ``geoface.track.headset_masks``)
    hmd_masks_true/000000.png  optional: the true ones (a renderer's), which the evaluation
                            scores with instead when present
    gt/000000.png           usage folders: the unoccluded frames, when known (evaluation)
    gt_static_upper/000000.png  optional, synthetic usage folders: the same frames with the
                            upper-face expression switched off (brows and lids at rest): where
                            they differ from gt/ is what the upper expression changes, which
                            the evaluation scores on its own (``evaluate_hmd``)
    head_poses.npz          optional: the tracked rigid head pose per frame, R [T, 3, 3], t [T, 3],
                            pivot [3] (X' = R (X − pivot) + pivot + t): a face tracker's in the
                            registration video, the headset's own 6-DoF tracking in the usage video

:func:`make_synthetic_hmd` writes a registration and a usage folder from the procedural head
with expressions that couple the upper and lower face (surprise raises the brows and opens the
jaw, a smile narrows the eyes, a frown purses the lips), a small head motion, a fixed camera,
and, in the usage folder, a rendered headset. The usage video is the *last* ``heldout`` fraction
of the sequence, the registration video the rest.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.camera import Camera, look_at
from geoface.errors import AvatarError
from geoface.images import save_image
from geoface.avatar.capture import euler_rotation, headset_mesh
from geoface.capture import Capture, write_camera, write_head_poses, write_landmarks
from geoface.errors import CaptureError

__all__ = ["HMDVideo", "load_video", "lower_face_box", "crop_lower_face", "make_synthetic_hmd", "LOWER_FACE_LANDMARKS", "UPPER_EXPRESSIONS", "expressions_from_drivers", "frame_input"]

LOWER_FACE_LANDMARKS = ("nose_tip", "mouth_left", "mouth_right", "chin")




# the expression weights of the synthetic sequences that move the upper face (above y_t)
UPPER_EXPRESSIONS = ("brow_raise", "eyes_closed_left", "eyes_closed_right")


@dataclass
class HMDVideo:
    """A loaded video folder (arrays in memory; frames float32 in [0, 1])."""

    frames: np.ndarray          # [T, H, W, 3]
    masks: np.ndarray           # [T, H, W] bool
    landmarks: np.ndarray       # [T, K, 2] pixels
    names: list
    camera: Camera
    y_split: float
    hmd_masks: np.ndarray | None = None   # [T, H, W] bool
    gt: np.ndarray | None = None          # [T, H, W, 3]
    mesh_path: Path | None = None
    poses: tuple | None = None            # (R [T, 3, 3], t [T, 3], pivot [3]) or None
    gt_static_upper: np.ndarray | None = None  # [T, H, W, 3]: gt with the upper expression at rest
    hmd_masks_true: np.ndarray | None = None  # [T, H, W] bool: the true headset masks (evaluation), when known

    def __len__(self) -> int:
        return len(self.frames)

    def crops(self, size: int = 128) -> np.ndarray:
        """[T, 3, size, size] float32 lower-face crops (from the landmarks)."""
        return np.stack([crop_lower_face(f, self.lower_landmarks(t), size) for t, f in enumerate(self.frames)])

    def boxes(self) -> np.ndarray:
        """[T, 3] float32: each crop's centre x, centre y and side divided by the image width and
        height — where the lower face is, which the crop itself no longer shows."""
        H, W = self.frames.shape[1:3]
        return np.array([[cx / W, cy / H, side / W] for cx, cy, side in
                         (lower_face_box(self.lower_landmarks(t)) for t in range(len(self)))], np.float32)

    def lower_landmarks(self, t: int) -> np.ndarray:
        idx = [self.names.index(n) for n in LOWER_FACE_LANDMARKS]
        return self.landmarks[t][idx]
















def load_video(folder, *, need_mesh: bool = False, frames: slice | None = None) -> HMDVideo:
    """Load a video folder (format in the module doc; read through :class:`geoface.capture.Capture`);
    every problem is a one-line CaptureError."""
    cap = Capture(folder, frames=frames)
    cap.require("landmarks.json", "camera.json", "meta.json")
    cam = cap.camera()
    meta = cap.meta(need=True)
    try:
        y_split = float(meta["y_split"])
    except (ValueError, KeyError, TypeError) as e:
        raise CaptureError(f"{cap.path}/meta.json: needs y_split, the upper/lower split in world metres "
                           f"({type(e).__name__}: {e})") from None
    lm = cap.landmarks()
    missing = [n for n in LOWER_FACE_LANDMARKS if n not in lm.names]
    if missing:
        raise CaptureError(f"{cap.path}/landmarks.json: missing landmarks {missing}")
    imgs = cap.frames()
    masks = cap.masks()
    masks = (masks > 0.5) if masks is not None else imgs.max(-1) > 0
    hmd = cap.images("hmd_masks")
    hmd_true = cap.images("hmd_masks_true")
    mesh = cap.head_mesh()
    if need_mesh and mesh is None:
        raise CaptureError(f"{cap.path}: a registration folder needs head.ply or head.obj (the canonical head)")
    return HMDVideo(imgs, masks, lm.points, lm.names, cam, y_split, None if hmd is None else hmd > 0.5,
                    cap.images("gt", True), mesh, cap.head_poses(), cap.images("gt_static_upper", True),
                    None if hmd_true is None else hmd_true > 0.5)


def lower_face_box(pts) -> tuple[float, float, float]:
    """Square crop (centre x, centre y, side) around nose tip, mouth corners and chin (pixels):
    from the nose tip down past the chin, as wide as 1.9× the mouth."""
    nose, ml, mr, chin = np.asarray(pts, dtype=np.float64)
    top, bottom = nose[1], chin[1]
    h = max(bottom - top, 1.0)
    w = max(abs(ml[0] - mr[0]) * 1.9, 1.0)
    side = 1.15 * max(h, w)
    cx = 0.5 * (ml[0] + mr[0])
    cy = top + 0.5 * side - 0.05 * side
    return float(cx), float(cy), float(side)


def crop_lower_face(frame, pts, size: int = 128) -> np.ndarray:
    """[3, size, size] float32 crop of ``frame`` [H, W, 3] around the lower face (zero padded)."""
    import cv2

    cx, cy, side = lower_face_box(pts)
    s = size / side
    # affine map: output pixel centre (u + .5) ← input (cx − side/2 + (u + .5)/s)
    M = np.array([[s, 0, -(cx - side / 2) * s], [0, s, -(cy - side / 2) * s]], dtype=np.float64)
    out = cv2.warpAffine(np.asarray(frame, np.float32), M, (size, size), flags=cv2.INTER_AREA
                         if s < 1 else cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return np.ascontiguousarray(out.transpose(2, 0, 1))


def frame_input(video, t: int, size: int, boxes: np.ndarray):
    """Frame ``t``'s lower-face crop [1, 3, size, size] and crop box [1, 3] as torch tensors
    (``boxes`` = ``video.boxes()``), as the HFM-GS encoder takes them."""
    import torch

    crop = torch.tensor(crop_lower_face(video.frames[t], video.lower_landmarks(t), size))[None]
    return crop, torch.tensor(boxes[t:t + 1])


# ----------------------------------------------------------------------------- synthetic data
def _drivers(T: int, rng) -> np.ndarray:
    """[T, 3] smooth activations in [0, 1] of (surprise, smile, frown): sums of slow sinusoids,
    shaped so each is often near 0 and sometimes near 1."""
    t = np.arange(T)[:, None] / max(T, 1)
    out = np.zeros((T, 3))
    for k in range(3):
        f = rng.uniform(4.0, 9.0, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        s = sum(np.sin(2 * np.pi * f[j] * t[:, 0] + ph[j]) / (j + 1) for j in range(3))
        out[:, k] = np.clip((s - 0.2) / 1.2, 0, 1) ** 1.2
    return out


def expressions_from_drivers(d) -> list[dict]:
    """Expression weights coupling upper and lower face: surprise = jaw_open + brow_raise, smile =
    smile + eyes narrowed, frown = frown + pucker."""
    out = []
    for s, m, a in np.asarray(d):
        out.append({"jaw_open": 0.8 * s, "brow_raise": s, "smile": m, "eyes_closed_left": 0.45 * m,
                    "eyes_closed_right": 0.45 * m, "frown": a, "pucker": 0.7 * a})
    return out






def make_synthetic_hmd(out, *, frames: int = 150, heldout: float = 0.2, res: int = 128,
                       n_vertices: int = 8000, seed: int = 0, motion: float = 1.0,
                       supersample: int = 2, quiet: bool | None = None) -> tuple[Path, Path]:
    """Write ``out/registration`` and ``out/usage`` (format in the module doc); returns both paths.

    The sequence has ``frames`` frames; the last ``heldout`` fraction is the usage video, rendered
    with a headset (``hmd_masks/``) and without it (``gt/``). ``motion`` scales the head motion
    (yaw ±8°, pitch ±4°, roll ±3°, a few millimetres of translation; 0 = a still head).
    """
    from geoface.progress import progress
    from geoface.nn.mesh_render import render_mesh
    from geoface.synth.head import head_model

    if frames < 5 or not 0 < heldout < 1:
        raise AvatarError(f"need frames >= 5 and 0 < heldout < 1; got {frames}, {heldout}")
    out = Path(out)
    rng = np.random.default_rng(seed)
    model = head_model(n_vertices, seed)
    neutral = model.mesh()
    lmk = neutral.landmarks
    y_eye, y_nose = neutral.eye_line_y, float(neutral.V[lmk["nose_tip"], 1])
    y_split = y_eye - 0.4 * (y_eye - y_nose)
    front = float(neutral.V[:, 2].max())
    target = np.array([0.0, 0.5 * (y_eye + float(neutral.V[lmk["chin"], 1])) + 0.01, 0.05])
    cam = look_at(target + [0, 0, 0.42], target, width=res, height=res, fov_y_deg=36.0)
    pivot = np.array([0.0, -0.09, 0.0])  # the neck
    hV, hF = headset_mesh(y_split, front)
    drivers = _drivers(frames, rng)
    exprs = expressions_from_drivers(drivers)
    tt = np.arange(frames) / frames
    ph = rng.uniform(0, 2 * np.pi, 6)
    # several cycles of each motion within the registration part, so that the held-out end of the
    # sequence revisits poses the registration saw (at other combinations)
    yaw = motion * np.radians(8) * np.sin(2 * np.pi * 5.3 * tt + ph[0])
    pitch = motion * np.radians(4) * np.sin(2 * np.pi * 7.1 * tt + ph[1])
    roll = motion * np.radians(3) * np.sin(2 * np.pi * 3.9 * tt + ph[2])
    trans = motion * 0.004 * np.stack([np.sin(2 * np.pi * 4.1 * tt + ph[3]), np.sin(2 * np.pi * 2.7 * tt + ph[4]),
                                       np.sin(2 * np.pi * 3.5 * tt + ph[5])], 1)
    n_reg = int(round(frames * (1 - heldout)))
    dirs = {"registration": out / "registration", "usage": out / "usage"}
    for d in dirs.values():
        for sub in ("frames", "masks"):
            (d / sub).mkdir(parents=True, exist_ok=True)
    for sub in ("hmd_masks", "gt", "gt_static_upper"):
        (dirs["usage"] / sub).mkdir(parents=True, exist_ok=True)
    names = list(lmk)
    Rs = {"registration": [], "usage": []}
    ts = {"registration": [], "usage": []}
    lm_pts = {"registration": [], "usage": []}
    log = {"registration": [], "usage": []}
    for t in progress(range(frames), "rendering HMD videos", total=frames, quiet=quiet):
        head = model.mesh(exprs[t])
        R = euler_rotation(yaw[t], pitch[t], roll[t])
        pose = lambda X: (np.asarray(X) - pivot) @ R.T + pivot + trans[t]  # noqa: E731
        V = pose(head.V)
        which = "registration" if t < n_reg else "usage"
        d = dirs[which]
        k = t if which == "registration" else t - n_reg
        name = f"{k:06d}.png"
        r = render_mesh(V, head.F, cam, head.colors, supersample=supersample)
        uv, _ = cam.project(V[[lmk[n] for n in names]])
        lm_pts[which].append(np.asarray(uv).tolist())
        Rs[which].append(R)
        ts[which].append(trans[t])
        log[which].append({"frame": k, "expression": exprs[t], "drivers": drivers[t].tolist(),
                           "yaw_pitch_roll_deg": np.degrees([yaw[t], pitch[t], roll[t]]).tolist(),
                           "translation": trans[t].tolist()})
        if which == "registration":
            save_image(d / "frames" / name, r.rgb * r.alpha[..., None])
            save_image(d / "masks" / name, (r.alpha > 0.5).astype(np.uint8) * 255)
        else:
            VV = np.concatenate([V, pose(hV)])
            FF = np.concatenate([head.F, hF + len(V)])
            CC = np.concatenate([head.colors[:, :3], np.full((len(hV), 3), 0.12)])
            ro = render_mesh(VV, FF, cam, CC, supersample=supersample)
            hmd = render_mesh(VV, FF, cam, np.concatenate([np.zeros((len(V), 3)), np.ones((len(hV), 3))]),
                              supersample=supersample).rgb[..., 0]
            save_image(d / "frames" / name, ro.rgb * ro.alpha[..., None])
            save_image(d / "masks" / name, (ro.alpha > 0.5).astype(np.uint8) * 255)
            save_image(d / "hmd_masks" / name, (hmd > 0.5).astype(np.uint8) * 255)
            save_image(d / "gt" / name, r.rgb * r.alpha[..., None])
            rest = model.mesh({**exprs[t], **{k: 0.0 for k in UPPER_EXPRESSIONS}})
            rs = render_mesh(pose(rest.V), rest.F, cam, rest.colors, supersample=supersample)
            save_image(d / "gt_static_upper" / name, rs.rgb * rs.alpha[..., None])
    from geoface.mesh.io import save_mesh

    for which, d in dirs.items():
        write_landmarks(d, lm_pts[which], names)
        write_head_poses(d, np.stack(Rs[which]), np.stack(ts[which]), pivot)
        write_camera(d, cam)
        (d / "meta.json").write_text(json.dumps({"y_split": y_split, "up": [0, 1, 0], "source": "procedural head",
                                                 "seed": seed, "n_vertices": n_vertices, "frames": log[which]}))
    save_mesh(dirs["registration"] / "head.ply", V=neutral.V, F=neutral.F, colors=neutral.colors)
    return dirs["registration"], dirs["usage"]
