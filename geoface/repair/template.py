"""The human head template: the ICT-FaceKit mean head registered to a scan (similarity, trimmed
ICP), which tells a human head from anything else, where its up and front are, and where its face
is — in any axis convention, unit or position.

The template is sampled uniformly by area (1500 points; the whole head, or the face region
alone for a scan of a face only), the scan likewise (2500).  ICP runs from 48 starting
rotations taken in the scan's own principal frame (the 24 rotations of the cube and 24 fixed
others), so the search does not depend on the file's axes; the six best starts are refined
for up to sixty iterations.  Each iteration pairs every template point with its nearest
scan point (the scan may hold more than a head: shoulders, a torso) — or, for a face only,
every scan point with its nearest template point — keeps the closest 60% and solves the best
similarity (Umeyama).  The starts use a third of the template's points, eight iterations each.  The fit is the trimmed mean distance over the template's RMS radius:
heads of real people and of the model fit at 0.029-0.038, an animal's head, a cow or a car at
0.05 and more.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..mesh.core import face_areas, face_normals

__all__ = ["TEMPLATE_FIT", "fit_head_template", "fit_head_template_from", "surface_samples", "template_face_region"]


def surface_samples(V, F, n, seed):
    """``n`` points spread uniformly by area over the surface, and their faces' unit normals."""
    A = face_areas(V, F)
    rng = np.random.default_rng(seed)
    f = rng.choice(len(F), size=n, p=A / A.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.column_stack([1 - s, s * (1 - r2), s * r2])
    return np.einsum("nk,nkd->nd", w, V[F[f]]), face_normals(V, F)[f]


#: a fit of the head template closer than this (trimmed mean distance over its RMS radius) is a
#: human head (heads of real people and the ICT-FaceKit model 0.029-0.037; an animal's head, a
#: cow, a car 0.05 and more)
TEMPLATE_FIT = 0.045
#: after the coarse search a shape fitting worse than this is not a head
COARSE_FIT = 0.08
_TEMPLATE_POINTS = 1500
SCAN_POINTS = 2500
_KEEP = 0.6


@lru_cache(maxsize=1)
def _template():
    """Surface samples of the ICT-FaceKit mean head (Y up, facing +Z): the whole head and the
    face region alone, or None when the model is not installed."""
    tpl = _template_mesh()
    if tpl is None:
        return None
    V, F, mask, _ = tpl
    whole = surface_samples(V, F, _TEMPLATE_POINTS, 1)[0]
    face = surface_samples(V, F[mask[F].all(1)], _TEMPLATE_POINTS, 2)[0]
    return whole, face


def _similarity(A, B):
    """``(s, R, t)`` minimising ``|s R A + t - B|`` (Umeyama)."""
    s, R, t = _similarity_many(A[None], B[None])
    return float(s[0]), R[0], t[0]


def _trimmed(d):
    """Indices of the closest ``_KEEP`` share of the distances ``d``."""
    m = int(_KEEP * len(d))
    return np.argpartition(d, m - 1)[:m]


def _icp(T, P, tree, R, s, t, iterations, template_to_scan, stop: float = 0.0):
    """Trimmed similarity ICP of template samples ``T`` onto scan samples ``P``: each template
    point to its nearest scan point (a scan with more than a head: shoulders, a torso), or each
    scan point to its nearest template point (a face only); the closest 60% of the pairs.
    ``stop``: end early once an iteration moves the trimmed mean distance by less than this
    share of it."""
    from scipy.spatial import cKDTree

    last = np.inf
    for _ in range(iterations):
        X = s * T @ R.T + t
        if template_to_scan:
            d, j = tree.query(X)
            k = _trimmed(d)
            s, R, t = _similarity(T[k], P[j[k]])
        else:
            d, j = cKDTree(X).query(P)
            k = _trimmed(d)
            s, R, t = _similarity(T[j[k]], P[k])
        e = float(d[k].mean())
        if stop and abs(last - e) <= stop * e:
            break
        last = e
    X = s * T @ R.T + t
    d = tree.query(X)[0] if template_to_scan else cKDTree(X).query(P)[0]
    return R, s, t, float(d[_trimmed(d)].mean())


def _similarity_many(A, B):
    """:func:`_similarity` for stacks ``A, B (k, m, 3)``: ``(s (k,), R (k, 3, 3), t (k, 3))``
    minimising each ``|s R A + t - B|`` (Umeyama)."""
    ma, mb = A.mean(1), B.mean(1)
    A0, B0 = A - ma[:, None], B - mb[:, None]
    U, D, Vt = np.linalg.svd(np.einsum("kmi,kmj->kij", B0, A0) / A.shape[1])
    sign = np.sign(np.linalg.det(U @ Vt))
    S = np.tile(np.eye(3), (len(A), 1, 1))
    S[:, 2, 2] = np.where(sign == 0, 1.0, sign)
    R = U @ S @ Vt
    s = (D * S[:, [0, 1, 2], [0, 1, 2]]).sum(1) / np.maximum((A0 ** 2).sum(2).mean(1), 1e-300)
    return s, R, mb - s[:, None] * np.einsum("kij,kj->ki", R, ma)


#: after this many iterations, a start whose trimmed error is more than :data:`PRUNE_RATIO` times
#: the best start's stops where it is (it has settled in another, worse fit than the best's)
PRUNE_AFTER = 10
PRUNE_RATIO = 1.5


def _icp_many(T, P, tree, starts, iterations, stop: float = 0.0):
    """:func:`_icp` (template to scan) from many starts ``[(R, s, t), ...]`` at once: one query
    of the scan's tree per iteration for all of them (each start stops on its own, and a start far
    behind the best after :data:`PRUNE_AFTER` iterations stops there)."""
    n = len(T)
    m = int(_KEEP * n)
    R = np.array([st[0] for st in starts], np.float64)
    s = np.array([st[1] for st in starts], np.float64)
    t = np.array([st[2] for st in starts], np.float64)
    active = np.ones(len(starts), bool)
    last = np.full(len(starts), np.inf)

    def query(idx):
        X = s[idx, None, None] * np.einsum("nj,kij->kni", T, R[idx]) + t[idx, None]
        d, j = tree.query(X.reshape(-1, 3), workers=-1)
        return d.reshape(len(idx), n), j.reshape(len(idx), n)

    for it in range(iterations):
        idx = np.flatnonzero(active)
        if not len(idx):
            break
        d, j = query(idx)
        k = np.argpartition(d, m - 1, axis=1)[:, :m]
        s[idx], R[idx], t[idx] = _similarity_many(T[k], P[np.take_along_axis(j, k, 1)])
        e = np.take_along_axis(d, k, 1).mean(1)
        if stop:
            active[idx[np.abs(last[idx] - e) <= stop * e]] = False
        last[idx] = e
        if it + 1 >= PRUNE_AFTER:
            active[idx[e > PRUNE_RATIO * last.min()]] = False
    d = query(np.arange(len(starts)))[0]
    e = np.take_along_axis(d, np.argpartition(d, m - 1, axis=1)[:, :m], 1).mean(1)
    return [(R[i], float(s[i]), t[i], float(e[i])) for i in range(len(starts))]


def _candidate_rotations(P):
    """Starting rotations in the samples' own principal frame (so that the search does not
    depend on the file's axes): the 24 rotations of the cube and 24 fixed others."""
    from scipy.spatial.transform import Rotation

    X = P - P.mean(0)
    w, E = np.linalg.eigh(X.T @ X)
    third = ((X @ E) ** 3).mean(0)
    E = E * np.where(third < 0, -1.0, 1.0)
    if np.linalg.det(E) < 0:
        E[:, 0] = -E[:, 0]
    group = np.concatenate([Rotation.create_group("O").as_matrix(), Rotation.random(24, random_state=0).as_matrix()])
    return [E @ G for G in group]


def fit_head_template(P, *, face_only: bool = False):
    """Register the head template to the scan samples ``P`` (similarity, trimmed ICP from 48
    starts): ``(R, s, t, error)`` with ``error`` the trimmed mean distance over the template's
    RMS radius (below :data:`TEMPLATE_FIT`: a human head), or None without the model."""
    from scipy.spatial import cKDTree

    tpl = _template()
    if tpl is None:
        return None
    T = tpl[1] if face_only else tpl[0]
    tree = cKDTree(P)
    cP, cT = P.mean(0), T.mean(0)
    rP = float(np.sqrt(((P - cP) ** 2).sum(1).mean()))
    rT = float(np.sqrt(((T - cT) ** 2).sum(1).mean()))
    s0 = rP / rT
    Tc = T[::3]  # the coarse search on a third of the template's points

    def icp(X, starts, iterations, stop=0.0):
        if face_only:  # scan to template: a tree of each start's template points
            return [_icp(X, P, tree, R, s, t, iterations, False, stop=stop) for R, s, t in starts]
        return _icp_many(X, P, tree, starts, iterations, stop=stop)

    fits = icp(Tc, [(R0, s0, cP - s0 * R0 @ cT) for R0 in _candidate_rotations(P)], 8)
    starts = sorted(((e / (s * rT), R, s, t) for R, s, t, e in fits), key=lambda x: x[0])
    # a shape far from any head after the coarse search (a sphere, a car: 0.1 and more, heads
    # below 0.06) is not refined further
    top = [(R, s, t) for _, R, s, t in starts[: 6 if starts[0][0] < COARSE_FIT else 1]]
    best = None
    for R, s, t, e in icp(T, top, 60, stop=1e-4):
        e = e / (s * rT)
        if best is None or e < best[3]:
            best = (R, s, t, e)
    return best


def fit_head_template_from(P, landmarks, *, face_only: bool = False):
    """Register the head template to the scan samples ``P`` from where the face's landmarks put
    it: the best similarity of the template's landmarks onto ``landmarks`` (``(68, 3)`` iBUG
    points, NaN where unknown, or the four key points of :func:`geoface.track.face3d.keypoints_of`),
    then trimmed ICP as in :func:`fit_head_template` from that one start. ``(R, s, t, error)``, or
    None without the model."""
    from scipy.spatial import cKDTree

    from ..track.face3d import INNER, keypoints_of, similarity

    tpl, lm = _template(), _template_landmarks()
    if tpl is None or lm is None:
        return None
    L = np.asarray(landmarks, np.float64)
    if len(L) == 4:
        A, B = keypoints_of(lm), L
    else:
        idx = [i for i in INNER if np.isfinite(L[i]).all()]
        A, B = lm[idx], L[idx]
    s, R, t = similarity(A, B)
    T = tpl[1] if face_only else tpl[0]
    rT = float(np.sqrt(((T - T.mean(0)) ** 2).sum(1).mean()))
    R, s, t, e = _icp(T, P, cKDTree(P), R, s, t, 30, not face_only, stop=1e-4)
    return R, s, t, e / (s * rT)


@lru_cache(maxsize=1)
def _template_landmarks():
    """The ICT-FaceKit mean head's 68 landmarks, or None when the model is not installed."""
    tpl = _template_mesh()
    return None if tpl is None else tpl[0][tpl[3]]


def turned_fit(P, fit, *, face_only: bool = False):
    """The template registered again from ``fit`` turned half a turn about its up axis (the face
    where the back of the head was): ``(R, s, t, error)``. A smooth, egg-shaped head can fit
    nearly as well either way round; how much worse this one fits says how sure ``fit`` is."""
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    tpl = _template()
    R, s, t, _ = fit
    T = tpl[1] if face_only else tpl[0]
    c = P.mean(0)
    half = Rotation.from_rotvec(np.pi * (R @ np.array([0.0, 1.0, 0.0]))).as_matrix()
    rT = float(np.sqrt(((T - T.mean(0)) ** 2).sum(1).mean()))
    R2, s2, t2, e = _icp(T, P, cKDTree(P), half @ R, s, half @ (t - c) + c, 60, not face_only, stop=1e-4)
    return R2, s2, t2, e / (s2 * rT)


def template_face_region(V, frame, *, reach: float = 0.08) -> np.ndarray | None:
    """The face of a human head: the vertices of ``V`` whose nearest point of the registered head
    template (``frame.template``) lies in the template's face region, within ``reach`` of the
    template's RMS radius.  None without a registration."""
    from scipy.spatial import cKDTree

    if frame.template is None:
        return None
    R, s, t = frame.template[:3]
    tpl = _template_mesh()
    if tpl is None:
        return None
    Vt, _, face, _ = tpl
    X = s * Vt @ R.T + t
    rT = s * float(np.sqrt(((Vt - Vt.mean(0)) ** 2).sum(1).mean()))
    d, j = cKDTree(X).query(np.asarray(V, float))
    return face[j] & (d < reach * rT)


@lru_cache(maxsize=1)
def _template_mesh():
    """The ICT-FaceKit mean head: (V, F, face mask), or None when the model is not installed (the
    other cues remain)."""
    try:
        from ..synth.ict import load_ict_model

        h = load_ict_model().head(None)
    except Exception:
        return None
    return h.V.copy(), h.F.copy(), h.face_mask.copy(), h.landmarks.copy()
