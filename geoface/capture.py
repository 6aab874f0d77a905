"""The capture folder: one reader and one writer for what both avatars learn a person from.

``geoface capture`` (a real clip), ``hmd synth`` and ``talk synth`` (renders) write it;
``track``, ``hmd``, ``talk`` and ``drive`` read it. A capture folder holds::

    frames/000000.png ...     RGB frames, background removed (black, or faded by a soft mask)
    masks/000000.png ...      optional: the person (8-bit, soft edges allowed; > 0.5 = person)
    landmarks.json            {"names": [K], "points": [T][K][2] pixels, "found": [T], "confidence": [T],
                              "tracker": str, "dense": file name or absent}; without "names", 68
                              points per frame are the iBUG 68 (IBUG68_NAMES); "found" / "confidence"
                              default to true / 1 (a renderer's)
    landmarks_dense.npz       optional: points [T, 468, 2] (MediaPipe's face mesh, pixels; NaN where not
                              found), found [T], confidence [T]
    camera.json               {"fx", "fy", "cx", "cy", "width", "height", "R", "t"} (OpenCV, world→camera)
    head_poses.npz            optional: the rigid head pose per frame, R [T, 3, 3], t [T, 3], pivot [3]
                              (X' = R (X − pivot) + pivot + t, X on the head mesh)
    expressions.npz           optional: weights [T, K] in [0, 1], names [K] (ICT-FaceKit / ARKit blendshapes)
    head.ply | head.obj       optional: the person's head (vertex colours) in the pose of frame 0
    audio.wav                 optional: the clip's sound
    meta.json                 {"fps", ...} and what each avatar adds (y_split, ...)

Each avatar adds files of its own (:mod:`geoface.hfm.data`, :mod:`geoface.thgs.data`). Every
problem reading a folder is a one-line :class:`~geoface.errors.CaptureError`; every file is
written atomically.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.camera import Camera
from geoface.errors import CaptureError
from geoface.landmarks import IBUG68_NAMES

__all__ = ["Capture", "Landmarks", "camera_from_json", "camera_to_json", "read_landmarks", "stack_frames",
           "write_landmarks", "write_camera", "write_head_poses", "write_expressions", "write_meta", "write_frame",
           "write_dense", "LANDMARKS", "DENSE"]

LANDMARKS = "landmarks.json"
DENSE = "landmarks_dense.npz"


def stack_frames(paths, rgb=True) -> np.ndarray:
    """The images of ``paths`` as one array; images of different sizes (or channel counts) are a
    one-line CaptureError naming the first that differs."""
    from geoface.images import read_image

    imgs = [read_image(p, "rgb" if rgb else "gray") for p in paths]
    for p, a in zip(paths, imgs):
        if a.shape != imgs[0].shape:
            raise CaptureError(f"{p}: {a.shape[1]}×{a.shape[0]}, but {Path(paths[0]).name} is "
                               f"{imgs[0].shape[1]}×{imgs[0].shape[0]}; every frame must have one size")
    return np.stack(imgs)


def camera_from_json(d) -> Camera:
    """A :class:`Camera` from ``camera.json``'s object (or the file's path): focal lengths
    positive, sizes in 1..16384, ``R`` a rotation, everything finite; else a one-line CaptureError."""
    where = "camera.json"
    if isinstance(d, (str, Path)):
        where = str(d)
        try:
            d = json.loads(Path(d).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
            raise CaptureError(f"{where}: not readable JSON ({type(e).__name__})") from None
    need = "needs fx, fy, cx, cy, width, height, R (3×3 rotation), t (3)"
    try:
        fx, fy, cx, cy = (float(d[k]) for k in ("fx", "fy", "cx", "cy"))
        w, h = d["width"], d["height"]
        R, t = np.asarray(d["R"], float), np.asarray(d["t"], float)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise CaptureError(f"{where}: {need} ({type(e).__name__}: {str(e)[:80]})") from None
    if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
        raise CaptureError(f"{where}: fx, fy must be positive and fx, fy, cx, cy finite")
    if any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 16384 for v in (w, h)):
        raise CaptureError(f"{where}: width and height must be integers in 1..16384; got {w!r}, {h!r}"[:200])
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise CaptureError(f"{where}: {need}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise CaptureError(f"{where}: R is not a rotation (R Rᵀ ≠ I or det < 0)")
    return Camera(fx, fy, cx, cy, int(w), int(h), R, t)


def camera_to_json(cam: Camera) -> dict:
    return {"fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy), "width": int(cam.width),
            "height": int(cam.height), "R": np.asarray(cam.R).tolist(), "t": np.asarray(cam.t).tolist()}


@dataclass(frozen=True)
class Landmarks:
    """A capture's ``landmarks.json``: ``points (T, K, 2)`` pixels, ``names [K]``, ``found (T,)``,
    ``confidence (T,)``, ``tracker`` (None: a renderer's)."""

    points: np.ndarray
    names: list
    found: np.ndarray
    confidence: np.ndarray
    tracker: str | None = None


def _landmarks_doc(path, n_frames: int) -> Landmarks:
    try:
        lm = json.loads(Path(path).read_text())
        pts = np.asarray(lm["points"], dtype=np.float64)
        names = [str(n) for n in lm["names"]] if "names" in lm else (
            list(IBUG68_NAMES) if pts.ndim == 3 and pts.shape[1] == 68 else None)
        if names is None:
            raise KeyError("'names' (needed unless the points are the 68 iBUG landmarks)")
        found = np.asarray(lm.get("found", [True] * len(pts)), bool)
        conf = np.asarray(lm.get("confidence", [1.0] * len(pts)), np.float64)
        tracker = lm.get("tracker")
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise CaptureError(f"{path}: malformed landmarks ({type(e).__name__}: {e})") from None
    if pts.ndim == 3 and pts.shape[1] != len(names):
        raise CaptureError(f"{path}: {len(names)} names but {pts.shape[1]} points per frame")
    if pts.ndim != 3 or pts.shape[0] != n_frames or pts.shape[2] != 2 or len(set(names)) != len(names):
        raise CaptureError(f"{path}: points must be [frames={n_frames}, K, 2] with K distinct names; got {pts.shape}")
    if not np.isfinite(pts).all():
        raise CaptureError(f"{path}: non-finite landmarks")
    if found.shape != (n_frames,) or conf.shape != (n_frames,) or not np.isfinite(conf).all():
        raise CaptureError(f"{path}: found and confidence must hold one value per frame ({n_frames})")
    return Landmarks(pts, names, found, conf, None if tracker is None else str(tracker))


def read_landmarks(path, n_frames: int) -> tuple[np.ndarray, list]:
    """(points [T, K, 2] pixels, names [K]) of a ``landmarks.json`` (module doc); every problem is
    a one-line CaptureError."""
    lm = _landmarks_doc(path, n_frames)
    return lm.points, lm.names


def _atomic_json(path: Path, doc) -> Path:
    from geoface._io import atomic_write_text

    atomic_write_text(path, json.dumps(doc))
    return path


def _atomic_npz(path: Path, **arrays) -> Path:
    from geoface._io import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return path


def write_landmarks(folder, points, names=None, *, found=None, confidence=None, tracker: str | None = None,
                    dense: str | None = None, extra: dict | None = None, name: str = LANDMARKS) -> Path:
    """``folder/landmarks.json`` (module doc) — the one writer of it. ``points (T, K, 2)``;
    ``names`` default the iBUG 68; ``extra``: more keys (a video's ``frames``, ``fps``, ...)."""
    pts = np.asarray(points, np.float64)
    names = list(IBUG68_NAMES) if names is None else [str(n) for n in names]
    T = len(pts)
    if pts.ndim != 3 or pts.shape[1:] != (len(names), 2):
        raise CaptureError(f"landmarks: points must be (T, {len(names)}, 2); got {pts.shape}")
    doc = {"names": names, "points": np.round(pts, 3).tolist(),
           "found": [bool(x) for x in (np.ones(T, bool) if found is None else found)],
           "confidence": [round(float(c), 4) for c in (np.ones(T) if confidence is None else confidence)]}
    if tracker is not None:
        doc["tracker"] = tracker
    if dense is not None:
        doc["dense"] = dense
    doc.update(extra or {})
    return _atomic_json(Path(folder) / name, doc)


def write_dense(folder, points, found, confidence) -> Path:
    """``folder/landmarks_dense.npz``: MediaPipe's 468 points per frame (module doc)."""
    return _atomic_npz(Path(folder) / DENSE, points=np.asarray(points, np.float32), found=np.asarray(found, bool),
                       confidence=np.asarray(confidence, np.float32))


def write_camera(folder, cam: Camera) -> Path:
    return _atomic_json(Path(folder) / "camera.json", camera_to_json(cam))


def write_head_poses(folder, R, t, pivot, name: str = "head_poses.npz") -> Path:
    R, t, pivot = (np.asarray(a, np.float64) for a in (R, t, pivot))
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (len(R), 3) or pivot.shape != (3,):
        raise CaptureError(f"head poses: R [T, 3, 3], t [T, 3], pivot [3]; got {R.shape}, {t.shape}, {pivot.shape}")
    return _atomic_npz(Path(folder) / name, R=R, t=t, pivot=pivot)


def write_expressions(folder, weights, names) -> Path:
    W = np.asarray(weights, np.float32)
    if W.ndim != 2 or W.shape[1] != len(names):
        raise CaptureError(f"expressions: weights must be (T, {len(names)}); got {W.shape}")
    return _atomic_npz(Path(folder) / "expressions.npz", weights=W, names=np.asarray([str(n) for n in names]))


def write_meta(folder, meta: dict) -> Path:
    return _atomic_json(Path(folder) / "meta.json", meta)


def write_frame(folder, t: int, img, sub: str = "frames") -> Path:
    """``folder/{sub}/{t:06d}.png``, written under a temporary name and renamed (never partial)."""
    from geoface.images import save_image

    path = Path(folder) / sub / f"{t:06d}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    save_image(path, img)
    return path


class Capture:
    """A capture folder (module doc), read lazily: each accessor reads and checks its file, and
    says in one line what is wrong. ``frames``: a slice of the frames to read (their landmarks,
    poses and images follow it)."""

    def __init__(self, folder, *, frames: slice | None = None):
        self.path = Path(folder)
        if not self.path.is_dir():
            raise CaptureError(f"{self.path}: not a folder")
        self.all_frame_paths = sorted((self.path / "frames").glob("*.png"))
        if not self.all_frame_paths:
            raise CaptureError(f"{self.path}: no frames/*.png")
        self.sel = frames
        self.frame_paths = self.all_frame_paths if frames is None else self.all_frame_paths[frames]

    def __len__(self) -> int:
        return len(self.frame_paths)

    @property
    def n_all(self) -> int:
        return len(self.all_frame_paths)

    def _cut(self, a):
        return a if self.sel is None or a is None else a[self.sel]

    def has(self, name: str) -> bool:
        return (self.path / name).exists()

    def require(self, *names: str, why: str = "") -> None:
        for n in names:
            if not (self.path / n).is_file():
                raise CaptureError(f"{self.path}: missing {n}{f' ({why})' if why else ''}")

    def frames(self, rgb: bool = True) -> np.ndarray:
        """``(T, H, W, 3)`` float32 in [0, 1]."""
        return stack_frames(self.frame_paths, rgb)

    def images(self, sub: str, rgb: bool = False):
        """The images of ``sub/`` named as the frames (masks, hmd_masks, gt, ...), or None when any
        is missing; a size other than the frames' is an error."""
        ps = [self.path / sub / p.name for p in self.frame_paths]
        if not all(p.is_file() for p in ps):
            return None
        a = stack_frames(ps, rgb)
        from geoface._io import image_size

        w, h = image_size(self.frame_paths[0])
        if a.shape[1:3] != (h, w):
            raise CaptureError(f"{self.path}/{sub}: images differ in size from frames/")
        return a

    def masks(self):
        """The person's masks ``(T, H, W)`` float in [0, 1] (soft edges kept), or None."""
        return self.images("masks", rgb=False)

    def landmarks(self, name: str = LANDMARKS) -> Landmarks:
        self.require(name)
        lm = _landmarks_doc(self.path / name, self.n_all)
        return Landmarks(self._cut(lm.points), lm.names, self._cut(lm.found), self._cut(lm.confidence), lm.tracker)

    def dense(self):
        """``(points (T, 468, 2), found (T,), confidence (T,))`` or None."""
        p = self.path / DENSE
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as d:
                pts, found, conf = (np.asarray(d[k]) for k in ("points", "found", "confidence"))
        except (OSError, KeyError, ValueError) as e:
            raise CaptureError(f"{p}: needs points [T, 468, 2], found [T], confidence [T] ({type(e).__name__})") from None
        if pts.shape != (self.n_all, 468, 2) or found.shape != (self.n_all,) or conf.shape != (self.n_all,):
            raise CaptureError(f"{p}: shapes {pts.shape}, {found.shape}, {conf.shape}; need [{self.n_all}, 468, 2], "
                               f"[{self.n_all}], [{self.n_all}]")
        return self._cut(pts.astype(np.float64)), self._cut(found.astype(bool)), self._cut(conf.astype(np.float64))

    def camera(self) -> Camera:
        self.require("camera.json")
        cam = camera_from_json(self.path / "camera.json")
        from geoface._io import image_size

        w, h = image_size(self.frame_paths[0])
        if (w, h) != (cam.width, cam.height):
            raise CaptureError(f"{self.path}: frames are {w}×{h} but camera.json says {cam.width}×{cam.height}")
        return cam

    def meta(self, need: bool = False) -> dict:
        p = self.path / "meta.json"
        if not p.is_file():
            if need:
                raise CaptureError(f"{self.path}: missing meta.json")
            return {}
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise CaptureError(f"{p}: not readable JSON ({type(e).__name__})") from None
        if not isinstance(d, dict):
            raise CaptureError(f"{p}: must hold a JSON object")
        return d

    def head_poses(self, name: str = "head_poses.npz"):
        """``(R [T, 3, 3], t [T, 3], pivot [3])`` or None."""
        p = self.path / name
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as d:
                R, t, piv = (np.asarray(d[k], np.float64) for k in ("R", "t", "pivot"))
        except (OSError, KeyError, ValueError) as e:
            raise CaptureError(f"{p}: needs R [T, 3, 3], t [T, 3], pivot [3] ({e})") from None
        n = self.n_all
        if R.shape != (n, 3, 3) or t.shape != (n, 3) or piv.shape != (3,) or not np.isfinite(R).all():
            raise CaptureError(f"{p}: shapes R {R.shape}, t {t.shape}, pivot {piv.shape} do not fit {n} frames")
        return self._cut(R), self._cut(t), piv

    def expressions(self):
        """``(weights [T, K], names [K])`` or None."""
        p = self.path / "expressions.npz"
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as d:
                W, names = np.asarray(d["weights"], np.float64), [str(n) for n in d["names"]]
        except (OSError, KeyError, ValueError) as e:
            raise CaptureError(f"{p}: needs weights [T, K], names [K] ({type(e).__name__})") from None
        if W.shape != (self.n_all, len(names)) or not np.isfinite(W).all():
            raise CaptureError(f"{p}: weights {W.shape} do not fit {self.n_all} frames and {len(names)} names")
        return self._cut(W), names

    def head_mesh(self) -> Path | None:
        return next((self.path / n for n in ("head.ply", "head.obj") if (self.path / n).is_file()), None)

    def audio(self) -> Path | None:
        p = self.path / "audio.wav"
        return p if p.is_file() else None
