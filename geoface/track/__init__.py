"""Tracking a face in video with real tools: what a user has instead of the renderer's oracle.

MediaPipe's face mesh (its wheel ships the models; nothing is downloaded) gives 468 points per
frame; :data:`IBUG68_FROM_MEDIAPIPE` turns them into the 68 iBUG landmarks that the avatars read
(each a fixed convex combination of four face-mesh points, fitted on rendered ICT-FaceKit
people against their true landmarks and checked on other people: ``data_tools/fit_mediapipe_ibug68.py``).
MediaPipe's selfie segmentation gives the person's mask. :func:`track_capture` writes a capture
folder (``frames/``, ``camera.json``, ...; :mod:`geoface.avatar.capture`) whose ``landmarks.json`` and ``masks/`` come from the
tracker: ``geoface track``.

Frames where no face is found get the landmarks of the nearest frames (linearly interpolated)
and are counted (:attr:`Tracking.found`); each frame also gets the face detector's confidence
(:attr:`Tracking.confidence`, MediaPipe's BlazeFace score, 0 where it finds no face). Video is
tracked from frame to frame (MediaPipe's video mode, which filters its landmarks itself); a One
Euro filter (:func:`one_euro`; Casiez, Roussel and Vogel 2012: a low-pass whose cut-off rises
with the landmarks' speed, so that a still head stops jittering while a fast turn is followed
without lag) can smooth them further. :func:`track_input` tracks an image, a folder of images or a video
file and writes the ``landmarks.json`` that capture folders read.

The 68 points are the Multi-PIE (iBUG) 68 that dlib and face-alignment write; the ICT-FaceKit
model's landmarks (:attr:`geoface.synth.ICTFaceModel.landmarks`) are the same 68, in the same
order, so a tracked frame fits the ICT head directly (:mod:`geoface.synth.ict_fit`).
"""
from __future__ import annotations

import contextlib
import importlib
import json
import sys
import types
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError, MissingDependencyError
from geoface.track.frames import TRACK_MAX_PIXELS, FrameSource, as_uint8, read_frames  # noqa: F401  (re-exported)
from geoface.track.headset import HEADSET_SEEDS, headset_masks  # noqa: F401  (re-exported)

__all__ = ["Tracking", "track_frames", "track_capture", "track_input", "read_frames", "FrameSource", "ibug68_from_mediapipe", "TRACKER",
           "facemesh_points", "face_confidence", "headset_masks", "HEADSET_SEEDS", "one_euro", "SMOOTHING"]

#: the tracker named in the landmarks files it writes
TRACKER = "mediapipe-facemesh"
_TABLE = Path(__file__).parents[1] / "data" / "mediapipe_ibug68.json"


def load_mediapipe():
    import os

    # MediaPipe's C++ side logs to stderr (glog/absl); a quiet library keeps it to errors
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    try:
        mp = _import_mediapipe()
    except ImportError as e:
        raise MissingDependencyError("face tracking needs MediaPipe: pip install 'geoface[track]' "
                                     "(mediapipe 0.10.21 --no-deps, absl-py, attrs, flatbuffers, protobuf<5)") from e
    return mp


class _Deferred(types.ModuleType):
    """A module as MediaPipe's drawing helpers see it (``matplotlib.pyplot``, and its package
    where that is not loaded): the real one, imported the first time one of them uses it.
    MediaPipe imports pyplot on start; geoface never draws with it, and it is most of
    MediaPipe's import time."""

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        if sys.modules.get(self.__name__) is self:
            del sys.modules[self.__name__]
        return getattr(importlib.import_module(self.__name__), name)


def _import_mediapipe():
    """``import mediapipe`` with matplotlib deferred (:class:`_Deferred`) unless pyplot is loaded
    already; nothing else changes: once MediaPipe is in, ``import matplotlib.pyplot`` anywhere
    gets the real module."""
    if "mediapipe" in sys.modules or "matplotlib.pyplot" in sys.modules:
        import mediapipe

        return mediapipe
    stubs = [_Deferred("matplotlib.pyplot")]
    if "matplotlib" not in sys.modules:  # `import matplotlib.pyplot as plt` takes pyplot from the package
        stubs.append(_Deferred("matplotlib"))
        stubs[1].pyplot = stubs[0]
    for stub in stubs:
        sys.modules[stub.__name__] = stub
    try:
        import mediapipe
    finally:
        for stub in stubs:
            if sys.modules.get(stub.__name__) is stub:
                del sys.modules[stub.__name__]
    return mediapipe


@lru_cache(maxsize=1)
def ibug68_from_mediapipe() -> tuple[np.ndarray, np.ndarray]:
    """(indices (68, k) into the 468 face-mesh points, weights (68, k), rows summing to 1)."""
    d = json.loads(_TABLE.read_text())
    idx, w = np.asarray(d["indices"], np.int64), np.asarray(d["weights"], np.float64)
    if idx.shape != w.shape or idx.shape[0] != 68 or idx.min() < 0 or idx.max() >= 468:
        raise GeofaceError(f"{_TABLE}: malformed landmark table")
    return idx, w


@contextlib.contextmanager
def quiet_native_stderr():
    """MediaPipe's C++ graph writes its set-up chatter (TFLite delegates, feedback tensors) straight
    to file descriptor 2, past Python's logging: hold it while the graph runs, unless the
    ``geoface`` logger is at DEBUG (``-v``)."""
    import logging
    import os
    import sys

    if logging.getLogger("geoface").isEnabledFor(logging.DEBUG):
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _each_frame(make_graph, frames, description: str, quiet, total: int | None = None):
    """``(frame as uint8, the graph's result)`` for each of ``frames`` (any iterable: a video
    streams through), with a progress bar. The graph's chatter comes while it is built and first
    run: both happen with fd 2 held."""
    from geoface.progress import progress

    it = iter(frames)
    try:
        first_frame = as_uint8(next(it))
    except StopIteration:
        return
    with quiet_native_stderr():
        graph = make_graph()
        first = graph.process(first_frame)

    def every():
        yield first_frame
        for f in it:
            yield as_uint8(f)

    n = total if total is not None else (len(frames) if hasattr(frames, "__len__") else None)
    try:
        for k, a in enumerate(progress(every(), description, total=n, quiet=quiet, unit="frames")):
            yield a, first if k == 0 else graph.process(a)
    finally:
        graph.close()


def facemesh_points(frames, *, video: bool = True, irises: bool = False, total: int | None = None,
                    quiet: bool | None = None) -> np.ndarray:
    """MediaPipe's 468 face-mesh points of each frame in pixels, ``(T, 468, 2)`` (NaN where no
    face is found); with ``irises`` its attention model's 478 (the last ten: the irises' centres and
    rims), ``(T, 478, 2)``. ``video``: track from frame to frame (MediaPipe's video mode). The
    68-point table was fitted on the 468-point model (``irises=False``)."""
    mp = load_mediapipe()
    n = 478 if irises else 468

    def graph():
        return mp.solutions.face_mesh.FaceMesh(static_image_mode=not video, max_num_faces=1, refine_landmarks=irises,
                                               min_detection_confidence=0.5, min_tracking_confidence=0.5)

    out = []
    for a, r in _each_frame(graph, frames, "tracking the face", quiet, total):
        if not r.multi_face_landmarks:
            out.append(np.full((n, 2), np.nan))
            continue
        lm = r.multi_face_landmarks[0].landmark
        out.append(np.array([[p.x * a.shape[1], p.y * a.shape[0]] for p in lm[:n]]))
    return np.stack(out) if out else np.zeros((0, n, 2))


def face_confidence(frames, *, quiet: bool | None = None) -> np.ndarray:
    """The face detector's confidence in each frame, ``(T,)`` in [0, 1]: MediaPipe's BlazeFace
    score of its best face (the full-range model, which also finds small and distant faces), 0
    where it finds none."""
    mp = load_mediapipe()
    out = []
    for _, r in _each_frame(lambda: mp.solutions.face_detection.FaceDetection(model_selection=1, min_detection_confidence=0.05),
                            frames, "detecting the face", quiet):
        out.append(max((float(d.score[0]) for d in (r.detections or []) if d.score), default=0.0))
    return np.asarray(out, np.float64)


#: the One Euro filter's settings for tracked landmarks (:func:`one_euro`): of the settings that
#: leave less jitter than MediaPipe's video mode alone on the validation person's talking capture,
#: the one with the least error still and in fast motion (``bench/bench_track.py``). The
#: video mode already filters its landmarks, so the gain is small and smoothing is off by default.
SMOOTHING = {"min_cutoff": 4.0, "beta": 30.0, "d_cutoff": 1.0}


def one_euro(points, fps: float, *, scale=None, min_cutoff: float = SMOOTHING["min_cutoff"],
             beta: float = SMOOTHING["beta"], d_cutoff: float = SMOOTHING["d_cutoff"]) -> np.ndarray:
    """Landmark tracks ``points (T, K, 2)`` smoothed by the One Euro filter (Casiez, Roussel and
    Vogel, CHI 2012): each point is low-passed with a cut-off frequency ``min_cutoff + beta ×
    speed`` (Hz), its speed itself low-passed at ``d_cutoff``. A still point is smoothed hard
    (jitter goes), a moving one lightly (no lag). The speed is in ``scale`` units per second
    (``scale`` (T,) or a number: the face's size in pixels, e.g. the outer eye corners' distance,
    so that the settings hold at any resolution; default 1: pixels). Causal (frame t uses frames
    ≤ t), so it runs on a live stream too; NaN rows (no face) restart the filter."""
    P = np.asarray(points, np.float64)
    if P.ndim != 3 or P.shape[2] != 2:
        raise GeofaceError(f"one_euro: points must be (T, K, 2); got {P.shape}")
    if not (fps > 0 and min_cutoff > 0 and beta >= 0 and d_cutoff > 0):
        raise GeofaceError(f"one_euro: fps, min_cutoff, d_cutoff > 0 and beta >= 0; got {fps}, {min_cutoff}, {d_cutoff}, {beta}")
    T = len(P)
    s = np.broadcast_to(np.asarray(1.0 if scale is None else scale, np.float64), (T,))
    te = 1.0 / fps

    def alpha(fc):
        return 1.0 / (1.0 + 1.0 / (2 * np.pi * fc * te))

    out = P.copy()
    prev, dprev = None, None
    for t in range(T):
        x = P[t]
        if not np.isfinite(x).all() or not (np.isfinite(s[t]) and s[t] > 0):
            prev, dprev = None, None
            continue
        if prev is None:
            prev, dprev = x, np.zeros(len(x))
            continue
        speed = np.linalg.norm(x - prev, axis=1) / te / s[t]
        dprev = dprev + alpha(d_cutoff) * (speed - dprev)
        a = alpha(min_cutoff + beta * dprev)[:, None]
        prev = prev + a * (x - prev)
        out[t] = prev
    return out


def person_masks(frames, *, quiet: bool | None = None) -> np.ndarray:
    """MediaPipe's selfie segmentation of each frame, ``(T, H, W)`` float in [0, 1]."""
    mp = load_mediapipe()
    return np.stack([np.asarray(r.segmentation_mask, np.float32) for _, r in _each_frame(
        lambda: mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0), frames, "segmenting the person", quiet)])


@dataclass(frozen=True)
class Tracking:
    """``landmarks (T, 68, 2)`` iBUG points in pixels (interpolated where no face was found);
    ``found (T,)`` bool; ``mesh (T, 468, 2)`` the face-mesh points (NaN where not found);
    ``masks (T, H, W)`` the person's segmentation, or None; ``confidence (T,)`` the face
    detector's score (None unless asked for); ``smoothed``: whether the landmarks went through
    :func:`one_euro`."""

    landmarks: np.ndarray
    found: np.ndarray
    mesh: np.ndarray
    masks: np.ndarray | None = None
    confidence: np.ndarray | None = None
    smoothed: bool = False


def _fill(P: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Frames without a face: the landmarks linearly interpolated between the found ones."""
    if found.all():
        return P
    t = np.arange(len(P))
    flat = P.reshape(len(P), -1).copy()
    for c in range(flat.shape[1]):
        flat[~found, c] = np.interp(t[~found], t[found], flat[found, c])
    return flat.reshape(P.shape)


def track_frames(frames, *, masks: bool = True, video: bool = True, fps: float | None = None, confidence: bool = False,
                 quiet: bool | None = None) -> Tracking:
    """Track ``frames`` ((T, H, W, 3) RGB, float in [0, 1] or uint8): the 68 iBUG landmarks from
    MediaPipe's face mesh and (``masks``) the person's segmentation. ``fps``: the frames are a
    video at that rate, and the landmarks are smoothed by :func:`one_euro` (None: not smoothed).
    ``confidence``: also the face detector's score per frame (:func:`face_confidence`)."""
    frames = list(frames)
    if not frames:
        raise GeofaceError("no frames to track")
    mesh = facemesh_points(frames, video=video, quiet=quiet)
    found = np.isfinite(mesh).all((1, 2))
    if not found.any():
        raise GeofaceError(f"no face found in any of the {len(frames)} frames")
    idx, w = ibug68_from_mediapipe()
    lm = np.einsum("tkjd,kj->tkd", mesh[:, idx], w)
    if fps is not None and len(frames) > 1:
        lm = one_euro(lm, fps, scale=np.linalg.norm(lm[:, 36] - lm[:, 45], axis=-1))
    lm = _fill(lm, found)
    return Tracking(landmarks=lm, found=found, mesh=mesh, masks=person_masks(frames, quiet=quiet) if masks else None,
                    confidence=face_confidence(frames, quiet=quiet) if confidence else None,
                    smoothed=fps is not None and len(frames) > 1)


def track_input(path, out_json, *, masks_dir=None, smooth: bool = False, fps: float | None = None,
                overwrite: bool = False, quiet: bool | None = None) -> Tracking:
    """Track an image, a folder of images (a video's frames) or a video file, and write
    ``out_json``: ``{"names": the 68 iBUG names, "points": [T, 68, 2] pixels, "found": [T],
    "confidence": [T], "frames": [T] names, "image_size": [W, H], "fps", "smoothed", "tracker"}``,
    the ``landmarks.json`` that capture folders read. ``masks_dir``: also the person's masks there,
    one PNG per frame. ``smooth``: a video or folder (more than one frame) is also smoothed by
    :func:`one_euro` at ``fps`` (default: the video's, else 25); MediaPipe's video mode already
    filters its landmarks, and on rendered talking people the extra filter takes off 4 % of the
    jitter at no cost in accuracy (``bench/bench_track.py``), so it is off by default."""
    from geoface._io import check_outputs, output_folder
    from geoface.capture import write_landmarks
    from geoface.images import save_image
    from geoface.landmarks import IBUG68_NAMES

    out_json = Path(out_json)
    if out_json.suffix.lower() != ".json":
        raise GeofaceError(f"{out_json}: the landmarks are written as JSON (name it .json)")
    if fps is not None and not (isinstance(fps, (int, float)) and np.isfinite(fps) and 0 < fps <= 1000):
        raise GeofaceError(f"fps must be a finite number in (0, 1000]; got {fps!r}")
    check_outputs([path], [out_json] + ([masks_dir] if masks_dir else []), force=overwrite)
    frames, names, rate = read_frames(path)
    rate = fps or rate or 25.0
    video = len(frames) > 1
    tr = track_frames(frames, masks=masks_dir is not None, video=video, fps=rate if smooth and video else None,
                      confidence=True, quiet=quiet)
    H, W = frames[0].shape[:2]
    if masks_dir is not None:
        with output_folder(Path(masks_dir), overwrite) as tmp:
            for n, m in zip(names, tr.masks):
                save_image(tmp / (Path(n).stem + ".png"), (m > 0.5).astype(np.uint8) * 255, atomic=False)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    write_landmarks(out_json.parent, tr.landmarks, IBUG68_NAMES, found=tr.found, confidence=tr.confidence,
                    tracker=TRACKER, name=out_json.name,
                    extra={"frames": names, "image_size": [W, H], "fps": rate if video else None, "smoothed": tr.smoothed})
    return tr


def track_capture(capture_dir, out_dir, *, masks: bool = True, names=None, headset: bool | None = None,
                  keep_originals: bool = False, overwrite: bool = False, quiet: bool | None = None) -> Tracking:
    """A copy of the capture folder ``capture_dir`` (frames, camera, head mesh, ...) in
    ``out_dir`` whose ``landmarks.json`` and ``masks/`` come from the tracker instead of the
    originals (not copied unless ``keep_originals``). ``names``: the landmark names to write (default: those of
    the capture's own ``landmarks.json`` when it has one, else all 68). ``headset`` (None: when
    the capture has ``hmd_masks/``): its ``hmd_masks/`` segmented from the frames
    (:func:`headset_masks`), the capture's own kept as ``hmd_masks_true/`` for evaluation.
    ``keep_originals``: keep the replaced ``landmarks.json`` and ``masks/`` too, as
    ``landmarks_true.json`` and ``masks_true/`` (a renderer's truth, for evaluation). ``out_dir``
    may be ``capture_dir`` itself (with ``overwrite``): the folder is replaced when complete."""
    from geoface._io import check_tree, copy_checked, output_folder
    from geoface.capture import Capture, write_dense, write_landmarks
    from geoface.landmarks import IBUG68_NAMES
    from geoface.images import read_image, save_image

    src = Path(capture_dir)
    check_tree(src)  # what it holds is copied: no loop, device or FIFO inside (before the tracking)
    cap = Capture(src)  # the one reader of capture folders
    files = cap.frame_paths
    if names is None and cap.has("landmarks.json"):
        try:
            names = cap.landmarks().names
        except GeofaceError:  # the capture's own landmarks are replaced: a broken file only loses its names
            names = None
    names = list(IBUG68_NAMES) if names is None else [str(n) for n in names]
    unknown = sorted(set(names) - set(IBUG68_NAMES))
    if unknown:
        raise GeofaceError(f"the tracker gives the 68 iBUG landmarks; not: {', '.join(unknown[:5])}")
    cols = [IBUG68_NAMES.index(n) for n in names]
    frames = [read_image(f) for f in files]
    tr = track_frames(frames, masks=masks, quiet=quiet)
    if headset is None:
        headset = (src / "hmd_masks").is_dir()
    hmd = headset_masks(frames, points=np.where(tr.found[:, None, None], tr.mesh, np.nan)) if headset else None
    with output_folder(Path(out_dir), overwrite) as tmp:
        for p in src.iterdir():
            if p.name == "landmarks_dense.npz":  # the tracker's own, written below
                continue
            if {"landmarks.json": True, "masks": masks, "hmd_masks": headset}.get(p.name):  # replaced below
                true = p.name.replace(".json", "_true.json") if p.suffix else p.name + "_true"
                if not ((src / true).exists() or (p.name != "hmd_masks" and not keep_originals)):
                    copy_checked(p, tmp / true)  # the truth, kept once
                continue
            copy_checked(p, tmp / p.name)
        for sub, ms in (("hmd_masks", hmd), ("masks", tr.masks if masks else None)):
            if ms is not None:
                (tmp / sub).mkdir()
                for f, m in zip(files, ms):
                    save_image(tmp / sub / f.name, (m > 0.5).astype(np.uint8) * 255, atomic=False)
        conf = face_confidence(frames, quiet=quiet)
        write_landmarks(tmp, tr.landmarks[:, cols], names, found=tr.found, confidence=conf, tracker=TRACKER)
        write_dense(tmp, tr.mesh, tr.found, conf)
    return tr
