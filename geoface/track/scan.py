"""Finding the face on a scan by looking at it: 3D face landmarks of a mesh in any pose.

A person finds the face of a scan by turning it until a face looks back; multi-view landmarking
of 3D faces does the same with a detector (Paulsen, Juhl and Larsen 2018, "Multi-view consensus
CNN for 3D facial landmark placement"). :func:`scan_landmarks` renders the mesh off-screen with
grey shading (:func:`geoface.track.look.render_grey`, our z-buffer
:func:`geoface.mesh.raster.rasterize_mesh`) and runs MediaPipe's face detector and face mesh on the
renders:

1. **Search.** 26 views from all round (the cube's faces, edges and corners, taken in the
   surface's own principal frame, so that the views do not depend on the file's axes), each
   image turned by 0, 90, 180 and 270 degrees (the detector finds faces rolled up to about 50
   degrees; the four turns go to the full-range face detector, BlazeFace, as one 2 × 2 mosaic).
   The best ten are looked at again, zoomed on what the detector saw and turned upright by its
   key points (eyes, nose, mouth; lifted onto the surface they give the face's own frame however
   obliquely the view saw it): a face scores high seen so, false alarms do not.
2. **Refine.** A camera in front of that guess, level with the eyes, the face filling the middle
   of a ``resolution``² image: the face mesh (468 points) gives the 68 iBUG landmarks
   (:func:`geoface.track.ibug68_from_mediapipe`), each lifted onto the surface by casting the ray
   through its pixel (:func:`geoface.track.look.lift`; a pixel that looks through a slit, an
   eyelid's seam, takes the nearer surface beside it). The landmarks give a better frame
   (:func:`geoface.track.face3d.face_frame`: the ICT-FaceKit head's axes after the best rotation
   of its landmarks onto these); the camera moves there and looks again, until the frame moves
   less than half a degree. Where the face mesh finds no face (its own detector is fussier: a
   masked face) other views and lighting are tried (:data:`geoface.track.look.STYLES`), and
   failing those the detector's four key points (eyes, nose tip, mouth) stand in for the 68.
3. **Consensus.** The face mesh runs on views turned about the face (left, right, above, below;
   ``views`` in all); every landmark is the median of its lifts over the views that see it, and
   the views' spread about that median (relative to the outer eye corners' distance) is reported.
4. **Mirror.** The landmarks fix the frame to a few degrees, most loosely in yaw; the surface
   about the face, mirrored about its midplane, fixes yaw and roll to a fraction of a degree
   (:func:`geoface.track.face3d.mirror_frame`, a reflective ICP). Where the surface has no mirror
   plane near the landmarks' (within 10°), the landmarks' frame is kept.

A face counts as found when the refined view's detector score is at least ``min_confidence`` and
the points look like a face in 3D: the nose in front of the eyes (a hollow mask, the inside of a
face scan seen from behind, has it behind them) and the nose and eye corners (or the four key
points) within :data:`MAX_SHAPE_ERROR` of the ICT-FaceKit head's after the best similarity.

Because the refined views are placed from the face itself, a head turned any way gives the same
renders up to resampling, and the same landmarks (``tests/track/test_scan.py``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from geoface.errors import GeofaceError

from .face3d import INNER, MIRROR_RADIUS, RIGID, eye_distance, face_frame, keypoint_frame, keypoints_of, mirror_frame
from .face3d import nose_out, shape_error, similarity, template_keypoints
from .look import STYLES, Looker, camera_at, lift, search_views, turn
from .search import FACE_HALF, search, verified

__all__ = ["ScanLandmarks", "scan_landmarks", "MIN_CONFIDENCE", "MAX_SHAPE_ERROR"]

#: the refined frontal view's face-detector score a face must reach (renders of real heads seen
#: from the front score 0.7-0.95; a sideways or face-up view finds nothing)
MIN_CONFIDENCE = 0.5
#: the nose's and eye corners' (or the four key points') RMS distance from the ICT-FaceKit head's
#: after the best similarity, over the eyes' distance, above which what was found is not taken as
#: a face (faces: 0.02-0.1)
MAX_SHAPE_ERROR = 0.2
#: where the mosaic search finds no face, the second search's resolution over the first's
FINE = 1.5
#: a landmark's pixel that shows a surface deeper than the nearest within a few pixels by more
#: than this share of the view's half width looks through a hole (an eyelid's seam, a nostril, an
#: open mouth): the landmark is lifted onto the nearer surface
HOLE_GAP = 0.1
#: the refined views look at the faces within this many half widths of the face's centre (the
#: camera stands 3.7 half widths away)
FOCUS = 4.0
#: turns of the consensus views about the face: (yaw, pitch) in degrees
CONSENSUS_TURNS = ((0.0, 0.0), (-22.0, 0.0), (22.0, 0.0), (0.0, 15.0), (0.0, -15.0), (-15.0, 10.0), (15.0, 10.0),
                   (-15.0, -10.0), (15.0, -10.0))
#: what the landmarks came from
SOURCES = ("face mesh", "face detector")


@dataclass(frozen=True)
class ScanLandmarks:
    """The face found on a mesh (:func:`scan_landmarks`).

    ``found``: whether a face was found; ``points (68, 3)``: the iBUG landmarks on the surface, in
    the mesh's coordinates (NaN where no view saw one; all NaN when not found, or when only the
    detector's key points were had); ``keypoints (4, 3)``: the subject's right eye's centre, the
    left's, the nose tip and the mouth's centre (NaN when not found); ``mesh_points (468, 3)``:
    MediaPipe's face-mesh points lifted likewise (None without); ``source``: "face mesh" or "face
    detector" (the face mesh found no face; the key points alone); ``confidence``: the face
    detector's score on the refined frontal render (0 when none); ``right``, ``up``, ``front``: the
    face's frame (unit, right-handed), None when not found; ``views``: how many consensus views
    saw the face; ``spread``: their mean distance from the consensus points over the eyes'
    distance; ``shape_error``: the points' RMS distance from the ICT-FaceKit head's after the best
    similarity, over the eyes' distance; ``mirror_turn``: how far (degrees) the surface's mirror
    plane through the face turned the landmarks' frame (:func:`geoface.track.face3d.mirror_frame`;
    NaN where the surface has none near the face, and the landmarks' frame is kept);
    ``mirror_error``: the mirrored surface's trimmed distance from itself over the mirrored
    ball's radius; ``why``: why no face was taken, when none was;
    ``seconds``: wall time; ``renders``: how many images were rendered."""

    found: bool
    points: np.ndarray
    keypoints: np.ndarray
    confidence: float = 0.0
    mesh_points: np.ndarray | None = field(default=None, repr=False)
    source: str = ""
    right: np.ndarray | None = None
    up: np.ndarray | None = None
    front: np.ndarray | None = None
    views: int = 0
    spread: float = float("nan")
    shape_error: float = float("nan")
    mirror_turn: float = float("nan")
    mirror_error: float = float("nan")
    why: str = ""
    seconds: float = 0.0
    renders: int = 0

    def to_dict(self, *, points: bool = True) -> dict:
        """A JSON-ready summary (``points``: with the 68 landmarks and the key points; NaN as None)."""
        d = {"found": bool(self.found), "source": self.source, "confidence": round(float(self.confidence), 4),
             "views": int(self.views), "spread": _num(self.spread), "shape_error": _num(self.shape_error),
             "mirror_turn": _num(self.mirror_turn), "mirror_error": _num(self.mirror_error), "why": self.why,
             "seconds": round(float(self.seconds), 3)}
        for k in ("right", "up", "front"):
            v = getattr(self, k)
            d[k] = None if v is None else [float(x) for x in v]
        if points:
            d["keypoints"] = [[_num(x) for x in p] for p in self.keypoints]
            d["points"] = [[_num(x) for x in p] for p in self.points]
        return d


def _num(x):
    x = float(x)
    return round(x, 6) if np.isfinite(x) else None


def _window(res: int) -> int:
    """The hole test's window (pixels either side) at a render size."""
    return max(2, int(res) // 64)


def scan_landmarks(V, F, *, resolution: int = 256, search_resolution: int = 128, views: int = 5,
                   min_confidence: float = MIN_CONFIDENCE, iterations: int = 4, candidates: int = 3,
                   source: str = "auto") -> ScanLandmarks:
    """Find the face on the mesh ``(V, F)`` by looking at it (module description): its 68 iBUG
    landmarks in 3D, in the mesh's coordinates, and its frame.

    Parameters
    ----------
    V : (n, 3) float, F : (m, 3) int — any triangle mesh (a scan, a bust, a face only, a head and
        shoulders), in any pose, unit and position.
    resolution : the refined renders' size (pixels a side).
    search_resolution : the search renders' size.
    views : consensus views (1-9): the refined frontal view, then left, right, above, below, ...
    min_confidence : the refined view's detector score a face must reach.
    iterations : most refinements of the frontal view (each renders and looks once more).
    candidates : the second looks' best faces (each looking its own way) refined in turn until
        one refines.
    source : "auto" (the face mesh's 68 landmarks, the detector's four key points where the face
        mesh finds no face), "face mesh" or "face detector" (only those).

    Returns a :class:`ScanLandmarks`; ``found`` False (with ``why``) when no face is seen. Raises
    :class:`geoface.errors.MissingDependencyError` without MediaPipe.

    Examples
    --------
    >>> from geoface.synth.ict import load_ict_model   # doctest: +SKIP
    >>> h = load_ict_model().head(None)                # doctest: +SKIP
    >>> r = scan_landmarks(h.V, h.F); r.found, r.up    # doctest: +SKIP
    (True, array([0.0..., 0.99..., 0.0...]))
    """
    from geoface.mesh.core import check_mesh, checked_meshes

    V, F = check_mesh(V, F)
    with checked_meshes():  # the renders and the lifts work on this mesh, checked once
        return _cached_scan(V, F, resolution, search_resolution, views, min_confidence, iterations, candidates, source)


def _cached_scan(V, F, resolution, search_resolution, views, min_confidence, iterations, candidates, source):
    key = (_digest(V, F), int(resolution), int(search_resolution), int(views), float(min_confidence), int(iterations),
           int(candidates), str(source))
    if key in _CACHE:
        return _CACHE[key]
    from geoface import _cache

    stored = _cache.get("face", repr(key))
    r = _from_json(stored) if stored is not None else None
    if r is None:
        r = _scan_landmarks(V, F, resolution, search_resolution, views, min_confidence, iterations, candidates, source)
        _cache.put("face", repr(key), _to_json(r))
    _CACHE[key] = r
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    return r


#: the last few meshes' faces are kept (per process): a dataset converts each mesh once per corner
#: set, a notebook converts the same scan again with other options; across processes with
#: ``GEOFACE_CACHE`` (:mod:`geoface._cache`)
CACHE_SIZE = 8
_CACHE: dict = {}
_ARRAYS = ("points", "keypoints", "mesh_points", "right", "up", "front")


def _to_json(r: ScanLandmarks) -> dict:
    """``r`` as JSON (arrays as lists, NaN kept: Python's JSON writes and reads it)."""
    from dataclasses import asdict

    d = asdict(r)
    for k in _ARRAYS:
        d[k] = None if d[k] is None else np.asarray(d[k], np.float64).tolist()
    return d


def _from_json(d: dict) -> ScanLandmarks | None:
    """The :class:`ScanLandmarks` of :func:`_to_json`, or None where it does not fit."""
    try:
        d = dict(d)
        for k in _ARRAYS:
            d[k] = None if d.get(k) is None else np.asarray(d[k], np.float64)
        r = ScanLandmarks(**d)
    except (TypeError, ValueError):
        return None
    return r if r.points.shape == (68, 3) and r.keypoints.shape == (4, 3) else None


def _digest(V, F) -> str:
    import hashlib

    h = hashlib.sha1(np.ascontiguousarray(V).tobytes())
    h.update(np.ascontiguousarray(F).tobytes())
    return h.hexdigest()


def _scan_landmarks(V, F, resolution, search_resolution, views, min_confidence, iterations, candidates, source):
    t0 = time.perf_counter()
    if not (1 <= int(views) <= len(CONSENSUS_TURNS)):
        raise GeofaceError(f"views must be in 1..{len(CONSENSUS_TURNS)}; got {views!r}")
    if int(resolution) < 64 or int(search_resolution) < 64:
        raise GeofaceError(f"resolution and search_resolution must be at least 64; got {resolution}, {search_resolution}")
    if source not in ("auto",) + SOURCES:
        raise GeofaceError(f"source must be one of auto, {', '.join(SOURCES)}; got {source!r}")
    nan68, nan4 = np.full((68, 3), np.nan), np.full((4, 3), np.nan)

    def none(why, conf=0.0):
        return ScanLandmarks(False, nan68, nan4, confidence=conf, why=why, seconds=time.perf_counter() - t0,
                             renders=look.renders)

    look = Looker(V, F)
    with look:
        look.coarse()
        refined, found = None, []
        # a small face (a head on shoulders, a bust on a plinth) may be missed in the mosaic: then
        # each turn of each view is looked at on its own, at a finer resolution
        lifts, seen = [], 0.0
        for res, mosaic in ((search_resolution, True), (int(FINE * search_resolution), False)):
            found = search(look, res, mosaic=mosaic)
            seen = max([seen] + [f[0] for f in found])
            for _, guess in (verified(look, found, search_resolution) if found else [])[: max(1, int(candidates))]:
                look.focus(guess[0], FOCUS * guess[3])
                refined = _refine(look, guess, resolution, iterations, source)
                if refined is None:
                    continue
                look.focus(refined[1], FOCUS * refined[4] * refined[5][0])
                lifts, lifts468, conf = _consensus_views(look, refined, resolution, int(views))
                if lifts:
                    break
            if lifts:
                break
            look.coarse()
        if not seen:
            return none(f"no face in any of {len(search_views())} views")
        if refined is None:
            return none(f"the detector saw a face (score {seen:.2f}) but found none from in front of it", float(seen))
    source = refined[-1]
    if not lifts:
        return none("what the detector saw is not a face: no view shows its nose in front of its eyes (a hollow mask, an animal)", conf)
    L = np.stack(lifts)
    if source == SOURCES[0]:
        P, P468, K = _consensus(L), _consensus(np.stack(lifts468)), None
        K = keypoints_of(P)
        right, up, front = face_frame(P)
        err, scale, sel = shape_error(P), eye_distance(P), list(INNER)
    else:
        P, P468, K = nan68, None, _consensus(L)
        right, up, front = keypoint_frame(K)
        err, scale, sel = _keypoint_shape_error(K), float(np.linalg.norm(K[1] - K[0])), slice(None)
    ref = P if source == SOURCES[0] else K
    spread = float(np.mean([np.nanmean(np.linalg.norm(x[sel] - ref[sel], axis=1)) for x in lifts])) / max(scale, 1e-300)
    why = ""
    if conf < min_confidence:
        why = f"the detector's score on the frontal view is {conf:.2f} (< {min_confidence:g})"
    elif nose_out(K, front) <= 0:
        why = "the nose is not in front of the eyes"
    elif np.isfinite(err) and err > MAX_SHAPE_ERROR:
        why = f"the points are not a face's (shape error {err:.2f} > {MAX_SHAPE_ERROR:g})"
    if why:
        return none(why, conf)
    # yaw and roll from the surface's mirror plane through the face, where it has one
    center = np.nanmean(ref[sel], axis=0)
    mirrored = mirror_frame(V, F, center, right, up, MIRROR_RADIUS * scale * (1.0 if source == SOURCES[0] else 1.5))
    mirror = {"turn": float("nan"), "error": float("nan")}
    if mirrored is not None:
        right, up, front, mirror = mirrored
    return ScanLandmarks(True, P, K, confidence=conf, mesh_points=P468, source=source, right=right, up=up, front=front,
                         views=len(lifts), spread=spread, shape_error=err, mirror_turn=mirror["turn"],
                         mirror_error=mirror["error"], seconds=time.perf_counter() - t0, renders=look.renders)


def _keypoint_shape_error(K) -> float:
    A = template_keypoints()
    if A is None:
        return float("nan")
    s, R, t = similarity(A, K)
    return float(np.sqrt(((s * A @ R.T + t - K) ** 2).sum(1).mean())) / max(float(np.linalg.norm(K[1] - K[0])), 1e-300)


def _observe(look, source, cam, st, res, half):
    """What one view shows: ``(the 68 landmarks (face mesh) or the four key points (face detector)
    lifted onto the surface, the face mesh's 468 lifted, the render)``; None for what was not
    found."""
    from geoface.track import ibug68_from_mediapipe

    img, face, depth = look.render(cam, st)
    hole = {"depth": depth, "window": _window(res), "gap": HOLE_GAP * half * st[0]}
    if source == SOURCES[0]:
        m = look.face_mesh(img)
        if m is None:
            return None, None, img
        idx, w = ibug68_from_mediapipe()
        P = lift(np.einsum("kjd,kj->kd", m[idx], w), cam, face, look.V, look.F, **hole)
        return P, lift(m, cam, face, look.V, look.F, **hole), img
    d = look.detect(img)
    return (None, None, img) if d is None else (lift(d[1][:4], cam, face, look.V, look.F, **hole), None, img)


def _frame_and_size(P, source):
    """(centre, front, up, half) of the refined view from the points a view gave."""
    if source == SOURCES[0]:
        _, up, front = face_frame(P)
        inner = P[list(INNER)]
        center = inner[np.isfinite(inner).all(1)].mean(0)
        height = float(np.linalg.norm(P[8] - P[27])) if np.isfinite(P[[8, 27]]).all() else 2.0 * eye_distance(P)
        return center, front, up, FACE_HALF * height
    _, up, front = keypoint_frame(P)
    return P[2], front, up, FACE_HALF * 2.0 * float(np.linalg.norm(P[1] - P[0]))


def _usable(P, source) -> bool:
    need = list(RIGID) if source == SOURCES[0] else slice(None)
    return bool(np.isfinite(P[need]).all())


def _refine(look, guess, res, iterations, source="auto"):
    """Look at the face from its front, level with its eyes, until the frame the landmarks give
    moves less than half a degree: ``(landmarks, centre, front, up, half, style, source)`` or None.
    While the face mesh finds no face the next of :data:`geoface.track.look.STYLES` is tried, and
    after them the detector's key points."""
    center, front, up, half = guess
    P = None
    plans = ([(SOURCES[0], st) for st in STYLES] if source != SOURCES[1] else []) + \
        ([(SOURCES[1], STYLES[0])] if source != SOURCES[0] else [])
    k = 0
    for _ in range(max(1, int(iterations)) + len(plans) - 1):
        source, st = plans[k]
        f2, u2 = turn(front, up, 0.0, st[3])
        obs = _observe(look, source, camera_at(center, f2, u2, half * st[0], res), st, res, half)
        if obs[0] is None or not _usable(obs[0], source):
            if P is None and k + 1 < len(plans):
                k += 1
                continue
            break
        if nose_out(keypoints_of(obs[0]) if source == SOURCES[0] else obs[0], f2) <= 0:
            return None  # a hollow face: the inside of a face scan, seen from behind
        P = obs[0]
        center, f1, u1, half = _frame_and_size(P, source)
        moved = np.degrees(np.arccos(np.clip(min(f1 @ front, u1 @ up), -1.0, 1.0)))
        front, up = f1, u1
        if moved < 0.5:
            break
    return None if P is None else (P, center, front, up, half, plans[k][1], plans[k][0])


def _consensus_views(look, refined, res, views):
    """The points lifted from each consensus view that finds the face with the nose in front:
    ``(lifts, the face mesh's 468 lifted (face mesh only), the frontal view's detector score)``."""
    _, center, front, up, half, st, source = refined
    lifts, lifts468, conf = [], [], 0.0
    for yaw, pitch in CONSENSUS_TURNS[:views]:
        f2, u2 = turn(front, up, yaw, pitch + st[3])
        P, P468, img = _observe(look, source, camera_at(center, f2, u2, half * st[0], res), st, res, half)
        if yaw == 0.0 and pitch == 0.0:
            r = look.detect(img)
            conf = 0.0 if r is None else float(r[0])
        if P is None or not _usable(P, source):
            continue
        if nose_out(keypoints_of(P) if source == SOURCES[0] else P, f2) > 0:
            lifts.append(P)
            if P468 is not None:
                lifts468.append(P468)
    return lifts, lifts468, conf


def _consensus(L) -> np.ndarray:
    """Per point, the coordinate-wise median of its lifts over the views that see it (NaN where
    none does)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: a point no view saw
        return np.nanmedian(L, axis=0)
