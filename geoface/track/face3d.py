"""A face in 3D from its landmarks: its frame (right, up, front), whether the points look like a
face's, and the ICT-FaceKit head's landmarks that both are measured against."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["INNER", "RIGID", "EYE_RIGHT", "EYE_LEFT", "face_frame", "keypoint_frame", "keypoints_of", "shape_error",
           "nose_out", "eye_distance", "template_landmarks", "template_keypoints", "similarity", "TEMPLATE_FILE",
           "mirror_frame", "MIRROR_RADIUS", "MIRROR_MAX_TURN", "MIRROR_MAX_ERROR"]

#: the iBUG landmarks that the frame and the shape check use: brows, nose, eyes, mouth (0-16, the
#: jaw line, are contour points: where the cheek turns away from each view)
INNER = tuple(range(17, 68))
#: the inner landmarks that move little with expressions: the nose and the eye corners
RIGID = (27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45)
EYE_RIGHT, EYE_LEFT = tuple(range(36, 42)), tuple(range(42, 48))


#: the ICT-FaceKit mean head's landmarks as our face finder sees them (``data_tools/fit_scan_template.py``)
TEMPLATE_FILE = Path(__file__).parents[1] / "data" / "scan_template.json"


@lru_cache(maxsize=1)
def _template():
    """``(68 landmarks, 4 key points)`` of the ICT-FaceKit mean head (Y up, facing +Z, cm) as
    :func:`geoface.track.scan.scan_landmarks` finds them on renders of it: the frame of a face
    compares like with like (MediaPipe's points are not the model's: its nose tip sits 3 mm lower,
    its eye corners 4 mm further in), so the mean head's own frame comes out as its axes. Without
    that file, the model's own landmarks; None without either."""
    import json

    try:
        d = json.loads(TEMPLATE_FILE.read_text())
        P, K = np.asarray(d["points"], np.float64), np.asarray(d["keypoints"], np.float64)
        if P.shape == (68, 3) and K.shape == (4, 3) and np.isfinite(P).all() and np.isfinite(K).all():
            return P, K
    except (OSError, ValueError, KeyError):
        pass
    try:
        from geoface.synth.ict import load_ict_model

        h = load_ict_model().head(None)
    except Exception:  # the model's files are optional to the tracker
        return None
    P = h.V[h.landmarks].copy()
    return P, keypoints_of(P)


def template_landmarks():
    """The ICT-FaceKit mean head's 68 landmarks as the face finder sees them (:func:`_template`),
    ``(68, 3)``, or None."""
    t = _template()
    return None if t is None else t[0]


def template_keypoints():
    """The mean head's four key points as the face detector gives them, ``(4, 3)``, or None."""
    t = _template()
    return None if t is None else t[1]


def keypoints_of(P) -> np.ndarray:
    """The face detector's four key points from 68 landmarks ``P (68, 3)``: the subject's right
    eye's centre, the left's, the nose tip, the mouth's centre, ``(4, 3)``."""
    P = np.asarray(P, np.float64)
    return np.stack([P[list(EYE_RIGHT)].mean(0), P[list(EYE_LEFT)].mean(0), P[30], P[[51, 57, 62, 66]].mean(0)])


def similarity(A, B):
    """``(s, R, t)`` minimising ``sum |s R a + t - b|^2`` over the rows of ``A``, ``B`` (Umeyama)."""
    ma, mb = A.mean(0), B.mean(0)
    A0, B0 = A - ma, B - mb
    U, D, Vt = np.linalg.svd(B0.T @ A0)
    S = np.eye(3)
    if np.linalg.det(U @ Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float((D * np.diag(S)).sum() / max((A0 ** 2).sum(), 1e-300))
    return s, R, mb - s * R @ ma


def _unit(v) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-300)


def eye_distance(P) -> float:
    """The outer eye corners' distance (iBUG 36 to 45)."""
    return float(np.linalg.norm(P[45] - P[36]))


def _frame_onto(T, P):
    _, R, _ = similarity(T, P)
    return R[:, 0].copy(), R[:, 1].copy(), R[:, 2].copy()


def face_frame(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(right, up, front)`` of a face from its 68 iBUG landmarks in 3D ``points (68, 3)``: the
    ICT-FaceKit head's axes (x right, y up, z front) after the best rotation of its inner landmarks
    (:data:`INNER`: brows, nose, eyes, mouth) onto these, fitted again without those further than
    twice the median from the first fit. Of the frames tried on heads turned at random (the nose
    and eye corners alone, the eye and mouth corners, with the eye line made level exactly), this
    one moved least with the turn. Without the model's files: the eye line, and up
    from the mouth to the eyes."""
    P = np.asarray(points, np.float64)
    T = template_landmarks()
    idx = np.array([i for i in INNER if np.isfinite(P[i]).all()])
    if T is not None and len(idx) >= 10:
        # trimmed: a few landmarks the face mesh put astray (a lip on a strong expression) are
        # left out of a second fit, those further from the first fit than twice the median
        s, R, t = similarity(T[idx], P[idx])
        d = np.linalg.norm(s * T[idx] @ R.T + t - P[idx], axis=1)
        keep = idx[d <= 2.0 * np.median(d)]
        return _frame_onto(T[keep], P[keep]) if len(keep) >= 10 else (R[:, 0].copy(), R[:, 1].copy(), R[:, 2].copy())
    return _frame_of_keypoints(keypoints_of(P))


def keypoint_frame(K) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(right, up, front)`` from the face detector's four key points in 3D ``K (4, 3)`` (eyes,
    nose tip, mouth: :func:`keypoints_of`), where the face mesh finds no face (a masked face): the
    ICT-FaceKit head's four after the best rotation onto these."""
    K = np.asarray(K, np.float64)
    T = template_keypoints()
    if T is not None:
        return _frame_onto(T, K)
    return _frame_of_keypoints(K)


def _frame_of_keypoints(K):
    right = _unit(K[1] - K[0])
    front = _unit(np.cross(right, 0.5 * (K[0] + K[1]) - K[3]))
    return right, np.cross(front, right), front


def shape_error(P) -> float:
    """RMS distance of the landmarks that expressions hardly move (:data:`RIGID`: the nose, the eye
    corners) from the ICT head's after the best similarity, over the outer eye corners' distance
    (NaN without the model's files): about 0.02-0.1 on faces, whatever their expression."""
    T = template_landmarks()
    idx = [i for i in RIGID if np.isfinite(P[i]).all()]
    if T is None or len(idx) < 6:
        return float("nan")
    s, R, t = similarity(T[idx], P[idx])
    X = s * T[idx] @ R.T + t
    return float(np.sqrt(((X - P[idx]) ** 2).sum(1).mean())) / max(eye_distance(P), 1e-300)


def nose_out(K, front) -> float:
    """How far the nose tip stands in front of the eyes' centres, over their distance, from the
    four key points ``K (4, 3)`` (a hollow face, seen from behind, has it negative)."""
    K = np.asarray(K, np.float64)
    return float((K[2] - 0.5 * (K[0] + K[1])) @ front) / max(float(np.linalg.norm(K[1] - K[0])), 1e-300)


#: the surface within this many outer-eye-corner distances of the face's centre is mirrored
#: (the face, the forehead, the cheeks: about 15 cm on an adult)
MIRROR_RADIUS = 1.6
#: the mirror plane is taken where it turns the landmarks' right by less than this (degrees;
#: measured 0.1-5.6 on the heads here) ...
MIRROR_MAX_TURN = 10.0
#: ... and the mirrored surface lies this close to itself (the trimmed mean distance of the mirrored
#: samples from the surface's tangent planes, over the radius: 0.01 is 1.5 mm on an adult's face;
#: the heads here 0.00002-0.0053, the ICT heads with the strongest expressions the most)
MIRROR_MAX_ERROR = 0.01
#: the share of mirrored samples that the fit keeps (the rest: where the surface has no mirror
#: image, an asymmetric expression, a cut, hair)
MIRROR_KEEP = 0.7


def mirror_frame(V, F, center, right, up, radius, *, samples: int = 20000, iterations: int = 30):
    """The face's frame turned so that ``right`` is the normal of the surface's plane of mirror
    symmetry near ``center``: ``(right, up, front, {"turn": degrees, "error": ...})``, or None where
    the plane is not found (it turns the frame by more than :data:`MIRROR_MAX_TURN`, or the surface
    is not symmetric about it: :data:`MIRROR_MAX_ERROR`).

    A face's landmarks fix its frame to a few degrees, most loosely in yaw (a masked face's, or
    where the face mesh guesses); the surface itself, mirrored about the face's midplane, fixes
    yaw and roll to a fraction of a degree. Points sampled on the surface within ``radius`` of
    ``center`` are mirrored about the plane (``right``, through ``center`` at first) and the plane
    is fitted by Gauss-Newton steps on the mirrored points' distances to the tangent planes of
    their nearest samples (a reflective ICP, point-to-plane, keeping the nearest
    :data:`MIRROR_KEEP`). ``up`` keeps its pitch: it is made orthogonal to the new right."""
    import trimesh
    from scipy.spatial import cKDTree

    V, F = np.asarray(V, np.float64), np.asarray(F)
    c, n = np.asarray(center, np.float64), _unit(np.asarray(right, np.float64))
    near = np.linalg.norm(V - c, axis=1) <= 1.3 * radius
    keep = near[F].any(1)
    if keep.sum() < 10:
        return None
    m = trimesh.Trimesh(V, F[keep], process=False)
    Y, fi = trimesh.sample.sample_surface(m, int(samples), seed=1)
    NY = m.face_normals[fi]
    X = Y[np.linalg.norm(Y - c, axis=1) <= radius][::5]
    if len(X) < 50:
        return None
    tree = cKDTree(Y)
    d = float(n @ c)
    for _ in range(int(iterations)):
        e1 = _unit(np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0]))
        e2 = np.cross(n, e1)
        s = X @ n - d
        Xr = X - 2.0 * s[:, None] * n
        j = tree.query(Xr)[1]
        M = NY[j]
        r = ((Xr - Y[j]) * M).sum(1)
        ok = np.abs(r) <= np.quantile(np.abs(r), MIRROR_KEEP)
        mn = M @ n
        # d(residual) for n -> n + a e1 + b e2 and d -> d + dd
        A = np.column_stack([-2.0 * (X @ e1) * mn - 2.0 * s * (M @ e1), -2.0 * (X @ e2) * mn - 2.0 * s * (M @ e2), 2.0 * mn])
        a, b, dd = np.linalg.lstsq(A[ok], -r[ok], rcond=None)[0]
        n1 = _unit(n + a * e1 + b * e2)
        moved = float(np.degrees(np.arccos(np.clip(n1 @ n, -1.0, 1.0))))
        n, d = n1, d + float(dd)
        if moved < 0.02:
            break
    Xr = X - 2.0 * (X @ n - d)[:, None] * n
    j = tree.query(Xr)[1]
    dist = np.abs(((Xr - Y[j]) * NY[j]).sum(1))  # to the tangent planes: free of the samples' spacing
    err = float(np.mean(np.sort(dist)[: max(1, int(MIRROR_KEEP * len(dist)))])) / max(float(radius), 1e-300)
    right0 = _unit(np.asarray(right, np.float64))
    if n @ right0 < 0:
        n = -n
    turn_deg = float(np.degrees(np.arccos(np.clip(n @ right0, -1.0, 1.0))))
    if turn_deg > MIRROR_MAX_TURN or err > MIRROR_MAX_ERROR:
        return None
    u = _unit(np.asarray(up, np.float64) - (np.asarray(up, np.float64) @ n) * n)
    return n, u, np.cross(n, u), {"turn": turn_deg, "error": err}
