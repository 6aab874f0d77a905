"""The capture folder that both avatars read (HFM-GS and THGS): frames as PNGs, the camera as
JSON, the 68 iBUG landmark names, head rotations, and the headset's proxy mesh.

A capture folder (HFM-GS registration or usage, THGS talking) holds::

    frames/000000.png ...   RGB frames, background removed (black)
    masks/000000.png ...    optional foreground masks (nonzero = person); default: frame != 0
    landmarks.json          {"names": [...], "points": [[[x, y], ...] per frame]} in pixels;
                            without "names", 68 points per frame are the iBUG 68 (IBUG68_NAMES)
    camera.json             {"fx", "fy", "cx", "cy", "width", "height", "R", "t"} (OpenCV, world→camera)
    head_poses.npz          optional: the tracked rigid head pose per frame, R [T, 3, 3], t [T, 3],
                            pivot [3] (X' = R (X − pivot) + pivot + t)

Each avatar adds files of its own (:mod:`geoface.hfm.data`, :mod:`geoface.thgs.data`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError
from geoface.camera import Camera
from geoface.splat.errors import SplatError
from geoface.images import read_image, save_image
from geoface.landmarks import IBUG68_LOWER, IBUG68_NAMES, IBUG68_RIGID  # noqa: F401  (re-exported)
from geoface.rotations import euler_rotation  # noqa: F401  (re-exported)

__all__ = ["track_synthetic", "IBUG68_NAMES", "IBUG68_LOWER", "IBUG68_RIGID", "write_frame", "stack_frames",
           "camera_from_json", "camera_to_json", "read_landmarks", "euler_rotation", "headset_mesh"]










def stack_frames(paths, rgb=True) -> np.ndarray:
    """The images of ``paths`` as one array; images of different sizes (or channel counts) are a
    one-line SplatError naming the first that differs."""
    imgs = [read_image(p, "rgb" if rgb else "gray") for p in paths]
    for p, a in zip(paths, imgs):
        if a.shape != imgs[0].shape:
            raise SplatError(f"{p}: {a.shape[1]}×{a.shape[0]}, but {Path(paths[0]).name} is "
                             f"{imgs[0].shape[1]}×{imgs[0].shape[0]}; every frame must have one size")
    return np.stack(imgs)


def write_frame(folder, t: int, img) -> Path:
    """``folder/frames/{t:06d}.png``, written under a temporary name and renamed (never partial)."""
    path = Path(folder) / "frames" / f"{t:06d}.png"
    save_image(path, img)  # atomic: never partial
    return path


def camera_from_json(d) -> Camera:
    """A :class:`Camera` from ``camera.json``'s object (or the file's path): focal lengths
    positive, sizes in 1..16384, ``R`` a rotation, everything finite; else a one-line SplatError."""
    where = "camera.json"
    if isinstance(d, (str, Path)):
        where = str(d)
        try:
            d = json.loads(Path(d).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
            raise SplatError(f"{where}: not readable JSON ({type(e).__name__})") from None
    need = "needs fx, fy, cx, cy, width, height, R (3×3 rotation), t (3)"
    try:
        fx, fy, cx, cy = (float(d[k]) for k in ("fx", "fy", "cx", "cy"))
        w, h = d["width"], d["height"]
        R, t = np.asarray(d["R"], float), np.asarray(d["t"], float)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise SplatError(f"{where}: {need} ({type(e).__name__}: {str(e)[:80]})") from None
    if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
        raise SplatError(f"{where}: fx, fy must be positive and fx, fy, cx, cy finite")
    if any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 16384 for v in (w, h)):
        raise SplatError(f"{where}: width and height must be integers in 1..16384; got {w!r}, {h!r}"[:200])
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise SplatError(f"{where}: {need}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise SplatError(f"{where}: R is not a rotation (R Rᵀ ≠ I or det < 0)")
    return Camera(fx, fy, cx, cy, int(w), int(h), R, t)


def camera_to_json(cam: Camera) -> dict:
    return {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width,
            "height": cam.height, "R": cam.R.tolist(), "t": cam.t.tolist()}


def read_landmarks(path, n_frames: int) -> tuple[np.ndarray, list]:
    """(points [T, K, 2] pixels, names [K]) of a ``landmarks.json`` (module doc); every problem is
    a one-line SplatError."""
    try:
        lm = json.loads(Path(path).read_text())
        pts = np.asarray(lm["points"], dtype=np.float64)
        names = [str(n) for n in lm["names"]] if "names" in lm else (
            list(IBUG68_NAMES) if pts.ndim == 3 and pts.shape[1] == 68 else None)
        if names is None:
            raise KeyError("'names' (needed unless the points are the 68 iBUG landmarks)")
    except (ValueError, KeyError, TypeError) as e:
        raise SplatError(f"{path}: malformed landmarks ({type(e).__name__}: {e})") from None
    if pts.ndim == 3 and pts.shape[1] != len(names):
        raise SplatError(f"{path}: {len(names)} names but {pts.shape[1]} points per frame")
    if pts.ndim != 3 or pts.shape[0] != n_frames or pts.shape[2] != 2 or len(set(names)) != len(names):
        raise SplatError(f"{path}: points must be [frames={n_frames}, K, 2] with K distinct names; got {pts.shape}")
    if not np.isfinite(pts).all():
        raise SplatError(f"{path}: non-finite landmarks")
    return pts, names


def headset_mesh(y_split: float, front_z: float, width: float = 0.19, height: float = 0.075,
                 depth: float = 0.07):
    """A box-shaped headset (V, F) in front of the upper face: bottom edge at ``y_split``, front face
    at ``front_z + 0.02``."""
    x0, x1 = -width / 2, width / 2
    y0, y1 = y_split, y_split + height
    z1 = front_z + 0.02
    z0 = z1 - depth
    V = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    # vertex index = 4·ix + 2·iy + iz; outward, counter-clockwise faces
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (1, 5, 7, 3), (0, 2, 6, 4)]
    F = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return V, F


def track_synthetic(folders, landmarks: str | None, head: str, *, quiet: bool | None = None) -> str:
    """The avatars' ``synth --landmarks``: with ``tracked`` (the default for ``head`` ``"ict"``),
    each synthetic capture folder's landmarks and masks replaced in place by the tracker's
    (:func:`geoface.track.track_capture`), the renderer's kept as ``*_true``; ``oracle`` leaves
    the renderer's. Returns the tail of the verb's summary line saying which the folders hold."""
    if (landmarks or ("tracked" if head == "ict" else "oracle")) == "oracle":
        return "; landmarks and masks: the renderer's (oracle)"
    from geoface.track import track_capture

    try:
        found = [track_capture(d, d, keep_originals=True, overwrite=True, quiet=quiet).found for d in folders]
    except GeofaceError as e:
        raise GeofaceError(f"{e} (--landmarks oracle keeps the renderer's)") from e
    return (f"; landmarks and masks tracked by MediaPipe (a face on {sum(int(f.sum()) for f in found)} of "
            f"{sum(len(f) for f in found)} frames; the renderer's kept as *_true)")
