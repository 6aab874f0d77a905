"""Real clips scored as the papers score them: a time split, a headset put on the test frames, the
trivial baselines, and one scorer for every method.

A capture folder made from a real clip (``geoface capture``) is split by time
(:func:`split_capture`): the first ``1 − test`` of the frames train an avatar (``train/``, a
registration folder with every file of the capture cut to those frames), the rest test it
(``test/``). The test folder is an HFM-GS usage folder: a headset — the box of
:func:`geoface.avatar.capture.headset_mesh`, its lower edge at the capture's ``y_split`` —
rendered over each real frame at the tracked head pose, in front of the tracked ICT head (what
the head hides of the headset stays hidden); ``gt/`` the real frames under it; ``hmd_masks/``
the pixels it covers; the 68 landmarks below it (a tracker on the headset video sees those);
``head_poses.npz`` the tracked poses (a headset's own 6-DoF tracking stands in for them); the
clip's sound cut to the same frames. THGS holds out the same last frames itself
(:func:`geoface.thgs.train.train_heldout_split` rounds as :func:`split_index` does).

Trivial baselines, computed on the same test frames (:func:`nearest_frame`, :func:`mean_face`):

* **nearest frame**: the training frame whose lower-face landmarks (68-point set below the
  headset, similarity-aligned) are nearest to the test frame's, warped to the test frame's tracked
  head pose through the tracked ICT head (each pixel the head covers at the test pose is fetched
  from where the same head point lies in the training frame; elsewhere the training frame as is);
* **mean face**: the pixel mean of the training frames (the crops follow the face).

:func:`score_regions` scores any prediction the same way: PSNR and SSIM over the person
(``person``), the face (inside the 468 landmarks' oval, ``face``), the mouth (a box around the 20
mouth landmarks, padded by a quarter of the mouth's width, ``mouth``) and the pixels the headset
hides (``occluded``).
"""
from __future__ import annotations

import shutil
import wave
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.errors import CaptureError

__all__ = ["TEST_FRACTION", "ClipSplit", "split_index", "split_capture", "usage_from_capture", "headset_frames", "nearest_frame",
           "mean_face", "regions", "score_regions", "HEADSET_RGB"]

#: the last fraction of a clip's frames that tests (the papers: 20 %)
TEST_FRACTION = 0.2
#: the headset's colour (a dark grey plastic, lit by a light at the camera)
HEADSET_RGB = (0.16, 0.17, 0.19)
_MOUTH = tuple(range(48, 68))
#: the test folder's subfolder with what only the scoring reads (all 68 and the 468 landmarks, the
#: tracked expressions): a headset user's tracker would not see the upper face
TRUTH = "truth"


def split_index(n: int, test: float = TEST_FRACTION) -> int:
    """Frames ``[0, k)`` train and ``[k, n)`` test (as THGS holds out its last frames)."""
    if not 0 < test < 1:
        raise CaptureError(f"the test fraction must be in (0, 1); got {test}")
    k = max(1, int(round(n * (1 - test))))
    if n - k < 2:
        raise CaptureError(f"a clip of {n} frames leaves {n - k} to test; need 2 or more")
    return k


@dataclass(frozen=True)
class ClipSplit:
    train: Path
    test: Path
    n_train: int
    n_test: int


def _cut_wav(src: Path, dst: Path, t0: float, t1: float) -> None:
    with wave.open(str(src), "rb") as r:
        sr, ch, width = r.getframerate(), r.getnchannels(), r.getsampwidth()
        r.setpos(min(int(t0 * sr), r.getnframes()))
        data = r.readframes(max(0, int((t1 - t0) * sr)))
    with wave.open(str(dst), "wb") as w:
        w.setnchannels(ch)
        w.setsampwidth(width)
        w.setframerate(sr)
        w.writeframes(data)


def _headset_world(meta: dict, F, labels, posed0) -> tuple[np.ndarray, np.ndarray]:
    """The headset box in the capture's world (the tracked head's frame-0 frame)."""
    from geoface.avatar.capture import headset_mesh

    V0 = posed0
    if "y_split" not in meta:
        raise CaptureError("the capture's meta.json has no y_split (the headset's lower edge)")
    front = float(V0[labels <= 1, 2].max())
    return headset_mesh(float(meta["y_split"]), front)


def headset_frames(folder, frames: np.ndarray, indices) -> tuple[np.ndarray, np.ndarray]:
    """The capture's ``frames`` (its frames ``indices``, [T, H, W, 3] float) with the headset drawn
    over them at the tracked head pose, and the headset's masks ([T, H, W] bool)."""
    from geoface.avatar.clip import capture_head
    from geoface.capture import Capture
    from geoface.gimage.raster import rasterize_mesh

    cap = Capture(folder)
    cam = cap.camera()
    F, labels, posed = capture_head(folder)
    R, t, piv = cap.head_poses()
    # the headset sits on the head as it is at rest (frame 0 of the world: the neutral head)
    hV, hF = _headset_world(cap.meta(), F, labels, _neutral(posed, R[0], t[0], piv))
    n, m = int(F.max()) + 1, len(F)
    FF = np.concatenate([F, hF + n])
    out, masks = frames.copy(), np.zeros(frames.shape[:3], bool)
    col = np.asarray(HEADSET_RGB)
    for j, k in enumerate(indices):
        Vh = (hV - piv) @ R[k].T + piv + t[k]
        V = np.concatenate([posed(k), Vh])
        face, _, _ = rasterize_mesh(V, FF, cam)
        hit = face >= m
        if hit.any():  # Lambert shading with a light at the camera
            fn = np.cross(V[FF[:, 1]] - V[FF[:, 0]], V[FF[:, 2]] - V[FF[:, 0]])
            fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)
            view = cam.center - V[FF].mean(1)
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            shade = 0.35 + 0.65 * np.abs((fn * view).sum(1))
            out[j][hit] = col * shade[face[hit], None]
        masks[j] = hit
    return out, masks


def _neutral(posed, R0, t0, piv):
    """Frame 0's head brought back to the world's rest pose (its own pose undone)."""
    return (posed(0) - piv - t0) @ R0 + piv


def _write_part(cap, d: Path, sl: slice, *, usage: bool, rgb=None, shown=None, hmd=None, gt: bool = False,
                extra=None, quiet=None) -> None:
    """The frames ``sl`` of the capture ``cap`` as a registration folder, or as a usage folder
    (``usage``: ``shown`` frames, ``hmd`` masks, the landmarks below a headset; the rest of the
    landmarks and the expressions in ``truth/`` and the real frames in ``gt/`` when ``gt``)."""
    from geoface.capture import (Capture, write_camera, write_dense, write_expressions, write_frame,
                                 write_head_poses, write_landmarks, write_meta)
    from geoface.landmarks import IBUG68_LOWER, IBUG68_NAMES
    from geoface.progress import progress

    part = Capture(cap.path, frames=sl)
    n = cap.n_all
    meta = cap.meta(need=True)
    fps = float(meta.get("fps", 25.0))
    d.mkdir()
    rgb = part.frames() if rgb is None else rgb
    masks = part.masks()
    shown = rgb if shown is None else shown
    for j in progress(range(len(part)), f"writing the {d.name} frames", total=len(part), quiet=quiet, unit="frames"):
        write_frame(d, j, shown[j])
        if masks is not None:
            write_frame(d, j, masks[j], "masks")
        if gt:
            write_frame(d, j, rgb[j], "gt")
        if hmd is not None:
            write_frame(d, j, hmd[j].astype(np.float32), "hmd_masks")
    lm = part.landmarks()
    kw = dict(found=lm.found, confidence=lm.confidence, tracker=lm.tracker)
    truth = d / TRUTH if usage else d
    if usage:  # what a tracker sees below a headset; the rest is kept for scoring
        keep = [lm.names.index(IBUG68_NAMES[i]) for i in IBUG68_LOWER]
        write_landmarks(d, lm.points[:, keep], [lm.names[i] for i in keep], **kw)
        truth.mkdir()
    write_landmarks(truth, lm.points, lm.names, **kw)
    dense = part.dense()
    if dense is not None:
        write_dense(truth, *dense)
    write_camera(d, part.camera())
    write_head_poses(d, *part.head_poses())
    write_expressions(truth, *part.expressions())
    m = {kk: (v[sl] if isinstance(v, list) and len(v) == n else v) for kk, v in meta.items()}
    m.update(extra or {})
    write_meta(d, m)
    if cap.head_mesh() is not None:
        shutil.copyfile(cap.head_mesh(), d / cap.head_mesh().name)
    if cap.audio() is not None:
        _cut_wav(cap.audio(), d / "audio.wav", sl.start / fps, sl.stop / fps)


def _need_track(folder):
    from geoface.capture import Capture

    cap = Capture(folder)
    cap.require("camera.json", "landmarks.json", "head_poses.npz", "expressions.npz", "meta.json",
                why="`geoface capture` writes it")
    return cap


def split_capture(folder, out, *, test: float = TEST_FRACTION, overwrite: bool = False,
                  quiet: bool | None = None) -> ClipSplit:
    """Write ``out/train`` and ``out/test`` (module doc) from the capture ``folder`` that
    ``geoface capture`` wrote; returns where they are and how many frames each has."""
    from geoface._io import atomic_dir, check_outputs
    from geoface.capture import Capture

    cap = _need_track(folder)
    out = Path(out)
    check_outputs([cap.path], [out], force=overwrite)
    n = len(cap)
    k = split_index(n, test)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        for name, sl in (("train", slice(0, k)), ("test", slice(k, n))):
            extra = dict(split=name, split_frames=[sl.start, sl.stop], split_of=str(cap.path), test_fraction=test)
            if name == "train":
                _write_part(cap, tmp / name, sl, usage=False, extra=extra, quiet=quiet)
            else:
                rgb = Capture(folder, frames=sl).frames()
                shown, hmd = headset_frames(folder, rgb, range(sl.start, sl.stop))
                _write_part(cap, tmp / name, sl, usage=True, rgb=rgb, shown=shown, hmd=hmd, gt=True, extra=extra,
                            quiet=quiet)
    return ClipSplit(out / "train", out / "test", k, n - k)


def usage_from_capture(folder, out, *, quiet: bool | None = None) -> Path:
    """A usage folder ``out`` from the capture of a real headset video (``geoface capture`` on it):
    its frames as they are, the headset's pixels segmented from them
    (:func:`geoface.track.headset_masks`, its colour learned where the face mesh's eyes fall), the
    landmarks below the headset,
    the tracked head poses. What ``geoface hmd remove MODEL VIDEO`` makes before it restores the
    face."""
    from geoface.track import headset_masks

    cap = _need_track(folder)
    hmd = cap.images("hmd_masks")  # segmented already by a headset capture (`capture_clip(headset=True)`)
    if hmd is None:
        dense = cap.dense()
        pts = None if dense is None else np.where(dense[1][:, None, None], dense[0], np.nan)
        hmd = headset_masks(np.round(cap.frames() * 255).astype(np.uint8), points=pts)
    else:
        hmd = hmd > 0.5
    out = Path(out)
    _write_part(cap, out, slice(0, len(cap)), usage=True, hmd=hmd, extra={"headset": "segmented from the frames"},
                quiet=quiet)
    return out


def _lower_shape(points: np.ndarray) -> np.ndarray:
    """[T, L, 2] → [T, L, 2] centred, unit RMS size (the similarity's scale and shift removed)."""
    P = points - points.mean(1, keepdims=True)
    return P / np.sqrt((P ** 2).sum((1, 2)) / P.shape[1])[:, None, None]


def _procrustes_dist(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Distances [Ta, Tb] between normalised shapes after the best rotation of each pair."""
    # with complex numbers the best 2D rotation of unit shapes is |<a, b>|
    a = A[..., 0] + 1j * A[..., 1]
    b = B[..., 0] + 1j * B[..., 1]
    c = np.abs(np.conj(a) @ b.T)  # [Ta, Tb]
    L = A.shape[1]
    return np.sqrt(np.maximum(2 * L - 2 * c, 0.0))


def nearest_frame(train, test, *, frames_train=None) -> tuple[np.ndarray, np.ndarray]:
    """Baseline (a): for each frame of the ``test`` folder, the ``train`` folder's frame whose
    lower-face landmarks are nearest, warped to the test frame's tracked head pose (module doc).
    Returns (images [T, H, W, 3] float32, the chosen training frames [T])."""
    from geoface.avatar.clip import capture_head
    from geoface.capture import Capture
    from geoface.gimage.raster import rasterize_mesh
    from geoface.landmarks import IBUG68_LOWER, IBUG68_NAMES
    from scipy.ndimage import map_coordinates

    tr, te = Capture(train), Capture(test)
    lower = [IBUG68_NAMES[i] for i in IBUG68_LOWER]

    def lower_points(c):
        lm = c.landmarks()
        try:
            return lm.points[:, [lm.names.index(nm) for nm in lower]]
        except ValueError:
            raise CaptureError(f"{c.path}/landmarks.json: needs the 68 points below a headset") from None

    d = _procrustes_dist(_lower_shape(lower_points(te)), _lower_shape(lower_points(tr)))
    pick = d.argmin(1)
    src = tr.frames() if frames_train is None else frames_train
    cam = te.camera()
    F, _, posed_tr = capture_head(train)
    R_tr, t_tr, piv = tr.head_poses()
    R_te, t_te, _ = te.head_poses()
    H, W = cam.height, cam.width
    out = np.empty((len(te), H, W, 3), np.float32)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    for j, s in enumerate(pick):
        X = posed_tr(s)  # the head as tracked in the training frame
        rest = (X - piv - t_tr[s]) @ R_tr[s]  # its pose undone ...
        Xt = rest @ R_te[j].T + piv + t_te[j]  # ... and the test frame's pose put on
        face, bary, _ = rasterize_mesh(Xt, F, cam)
        uv = np.asarray(cam.project(X)[0])
        hit = face >= 0
        xs, ys = xx.copy(), yy.copy()
        q = (uv[F[face[hit]]] * bary[hit][:, :, None]).sum(1) - 0.5  # pixel centres at +0.5
        xs[hit], ys[hit] = q[:, 0], q[:, 1]
        for c in range(3):
            out[j, ..., c] = map_coordinates(src[s, ..., c], [ys, xs], order=1, mode="nearest")
    return out, pick


def mean_face(train, n_test: int) -> np.ndarray:
    """Baseline (b): the pixel mean of the ``train`` folder's frames, once per test frame."""
    from geoface.capture import Capture

    m = Capture(train).frames().mean(0)
    return np.broadcast_to(m, (n_test, *m.shape)).astype(np.float32)


def regions(test) -> dict[str, np.ndarray]:
    """The scored regions of the ``test`` folder's frames, [T, H, W] bool each (module doc)."""
    from skimage.draw import polygon

    from geoface.avatar.clip import FACE_OVAL
    from geoface.capture import Capture

    te = Capture(test)
    gt = te.images("gt", rgb=True)
    if gt is None:
        raise CaptureError(f"{te.path}: no gt/ (a test folder from split_capture)")
    T, H, W = gt.shape[:3]
    masks = te.masks()
    person = masks > 0.5 if masks is not None else gt.max(-1) > 0
    hmd = te.images("hmd_masks")
    occluded = (hmd > 0.5) & person if hmd is not None else np.zeros_like(person)
    from geoface.capture import read_landmarks

    dense = None
    if (te.path / TRUTH / "landmarks_dense.npz").is_file():
        with np.load(te.path / TRUTH / "landmarks_dense.npz", allow_pickle=False) as z:
            dense = np.asarray(z["points"], np.float64), np.asarray(z["found"], bool)
    pts68, names = read_landmarks(te.path / TRUTH / "landmarks.json", T)
    face = np.zeros_like(person)
    mouth = np.zeros_like(person)
    for j in range(T):
        if dense is not None and dense[1][j]:
            oval = dense[0][j][list(FACE_OVAL)]
            rr, cc = polygon(oval[:, 1] - 0.5, oval[:, 0] - 0.5, (H, W))
            face[j, rr, cc] = True
        mp = pts68[j, list(_MOUTH)]
        pad = 0.25 * (mp[:, 0].max() - mp[:, 0].min())
        x0, x1 = (int(np.clip(v, 0, W)) for v in (mp[:, 0].min() - pad, mp[:, 0].max() + pad + 1))
        y0, y1 = (int(np.clip(v, 0, H)) for v in (mp[:, 1].min() - pad, mp[:, 1].max() + pad + 1))
        mouth[j, y0:y1, x0:x1] = True
    return {"person": person, "face": face & person, "mouth": mouth, "occluded": occluded}


def score_regions(pred, gt, regs: dict[str, np.ndarray]) -> dict:
    """Mean PSNR (dB) and SSIM of ``pred`` against ``gt`` ([T, H, W, 3] in [0, 1]) over each
    region of ``regs`` (frames where the region is empty are left out), and per-frame PSNR."""
    from geoface.splat.fit import psnr, ssim_masked

    out = {}
    for name, m in regs.items():
        ps, ss = [], []
        for j in range(len(gt)):
            if m[j].sum() < 16:
                ps.append(np.nan)
                continue
            ps.append(psnr(pred[j], gt[j], m[j]))
            ss.append(ssim_masked(pred[j], gt[j], m[j]))
        ps = np.asarray(ps, np.float64)
        out[f"psnr_{name}"] = float(np.nanmean(ps)) if np.isfinite(ps).any() else float("nan")
        out[f"ssim_{name}"] = float(np.mean(ss)) if ss else float("nan")
        out[f"psnr_{name}_frames"] = [round(float(v), 2) for v in ps]
    return out
