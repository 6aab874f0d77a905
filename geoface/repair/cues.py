"""The shape's own cues to which way a surface stands: its opening (a neck, the rim of a face
scan), its plane of mirror symmetry, a flat cut on its convex hull (a bust's base), the plane it
rests on, a standing figure's long axis. :func:`geoface.repair.upright.upright_frame` decides with
them where no face is seen, and checks the face's frame against them where one is."""

from __future__ import annotations

import numpy as np

from ..mesh.core import boundary_loops, face_areas, loop_length
from .template import fit_head_template

__all__ = ["opening", "mirror_plane", "flat_bottom", "resting_plane", "standing_figure", "unit", "orthogonal"]


def unit(v) -> np.ndarray:
    """``v`` over its length."""
    v = np.asarray(v, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-300)


def orthogonal(v, to) -> np.ndarray:
    """``v`` made orthogonal to the unit ``to``, and unit."""
    return unit(v - (v @ to) * to)


def opening(V, F, min_opening: float = 0.1):
    """The longest boundary loop, if it is a real opening: (loop, its plane's normal pointing
    into the surface, depth of the surface beyond it / its width, its length / sqrt(area),
    ambiguous) or None.  ``ambiguous``: another loop is more than half as long, so the longest
    may be one hole among holes of its size (a closed scan with holes) - a caller with a better
    cue (the head template) decides."""
    loops = boundary_loops(F)
    if not loops:
        return None
    lengths = [loop_length(V, lp) for lp in loops]
    k = int(np.argmax(lengths))
    loop = loops[k]
    area = float(face_areas(V, F).sum())
    if len(loop) < 8 or lengths[k] < min_opening * np.sqrt(area):
        return None
    ambiguous = len(loops) > 1 and sorted(lengths)[-2] > 0.5 * lengths[k]
    P = V[loop]
    c = P.mean(0)
    _, _, vt = np.linalg.svd(P - c, full_matrices=False)
    n = vt[2]
    A = face_areas(V, F)
    g = (A[:, None] * V[F].mean(1)).sum(0) / A.sum()
    if (g - c) @ n < 0:
        n = -n
    Q = P - c
    inplane = Q - np.outer(Q @ n, n)
    width = 2.0 * float(np.sqrt((inplane ** 2).sum(1).mean())) * np.sqrt(2.0)  # ~ the diameter of a circle
    depth = float(((V[np.unique(F)] - c) @ n).max())
    return loop, n, depth / max(width, 1e-300), lengths[k] / np.sqrt(area), ambiguous


def mirror_plane(P, axis_of_rotation=None, *, steps: int = 60):
    """The plane of mirror symmetry through the samples' centroid: its unit normal and the
    mean mirror error (relative to the size).  With ``axis_of_rotation`` the plane contains that
    axis (the normal is searched in the orthogonal circle); else every direction of a
    hemisphere.  A coarse grid, then local refinement."""
    from scipy.spatial import cKDTree

    c = P.mean(0)
    X = P - c
    R = float(np.sqrt((X * X).sum(1).mean()))
    tree = cKDTree(X)
    sub = X[:: max(1, len(X) // 1500)]

    def err(a):
        a = unit(a)
        return float(tree.query(sub - 2.0 * np.outer(sub @ a, a))[0].mean()) / R

    if axis_of_rotation is not None:
        ax = unit(axis_of_rotation)
        e1 = orthogonal(np.array([1.0, 0.0, 0.0]) if abs(ax[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), ax)
        e2 = np.cross(ax, e1)
        th = np.linspace(0, np.pi, steps, endpoint=False)
        errs = np.array([err(np.cos(t) * e1 + np.sin(t) * e2) for t in th])
        k = int(np.argmin(errs))
        t0, dt = th[k], np.pi / steps
        for _ in range(12):  # golden-section-like refinement
            cand = [t0 - dt / 2, t0, t0 + dt / 2]
            e = [err(np.cos(t) * e1 + np.sin(t) * e2) for t in cand]
            t0 = cand[int(np.argmin(e))]
            dt /= 2
        a = np.cos(t0) * e1 + np.sin(t0) * e2
        return unit(a), err(a), float(np.median(errs))
    # hemisphere: a Fibonacci grid of directions, then local refinement on the sphere
    m = 200
    i = np.arange(m) + 0.5
    z = i / m
    phi = np.pi * (1 + 5 ** 0.5) * i
    D = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    errs = np.array([err(d) for d in D])
    best = D[int(np.argmin(errs))]
    step = 0.1
    cur = err(best)
    for _ in range(30):
        improved = False
        u = orthogonal(np.array([1.0, 0.0, 0.0]) if abs(best[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), best)
        v = np.cross(best, u)
        for d in (u, -u, v, -v):
            cand = unit(best + step * d)
            e = err(cand)
            if e < cur:
                best, cur, improved = cand, e, True
        if not improved:
            step /= 2
            if step < 1e-3:
                break
    return best, cur, float(np.median(errs))


def flat_bottom(V, F, P, Pn, diag):
    """The largest flat region of the surface that lies on its convex hull (a cut): its outward
    normal and its share of the surface, or (None, 0)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(P)
    except QhullError:
        return None, 0.0, 0.0
    eq = hull.equations  # outward normals and offsets: n . x + d = 0
    tol = 2e-3 * diag
    best, share, second = None, 0.0, 0.0
    seen: list = []
    order = np.argsort(-_facet_areas(P, hull.simplices))
    for f in order[:200]:
        n, d = eq[f, :3], eq[f, 3]
        if any(abs(n @ m) > 0.996 and abs(d - e) < tol for m, e in seen):
            continue
        seen.append((n, d))
        on = (np.abs(P @ n + d) < tol) & (Pn @ n > 0.98)
        s = float(on.mean())
        if s > share:
            best, second, share = n, share, s
        elif s > second:
            second = s
    return best, share, second


def _facet_areas(P, simplices):
    A, B, C = P[simplices[:, 0]], P[simplices[:, 1]], P[simplices[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)


def resting_plane(P, diag, lateral=None):
    """The plane the shape stands on: among the convex hull's facet planes on which it is stable
    (its centroid projects inside the support polygon) and, for a mirror-symmetric shape, whose
    normal lies within 20° of the symmetry plane (``lateral``: its normal; a shape does not stand
    on its flank), the one touched in the most separate places (a quadruped's four feet, a
    table's legs), ties going to the larger stability margin.  (outward normal, contacts,
    margin relative to the size, the runner-up's contacts) or None."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    try:
        hull = ConvexHull(P)
    except QhullError:
        return None
    g = P.mean(0)
    tol = 0.01 * diag
    scored = []
    done: list = []
    for f in np.argsort(-_facet_areas(P, hull.simplices))[:300]:
        n, d = hull.equations[f, :3], hull.equations[f, 3]
        if any(n @ m > 0.995 for m in done):
            continue
        done.append(n)
        if lateral is not None and abs(n @ lateral) > np.sin(np.radians(20.0)):
            continue
        on = P[np.abs(P @ n + d) < tol]
        if len(on) < 3:
            continue
        e1 = orthogonal(np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), n)
        e2 = np.cross(n, e1)
        Q = np.column_stack([on @ e1, on @ e2])
        c = np.array([g @ e1, g @ e2])
        try:
            poly = ConvexHull(Q)
        except QhullError:
            continue
        margin = float(-(poly.equations[:, :2] @ c + poly.equations[:, 2]).max()) / diag
        if margin <= 0:
            continue
        pairs = cKDTree(Q).query_pairs(0.05 * diag, output_type="ndarray")
        G = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(Q), len(Q)))
        contacts = int(connected_components(G, directed=False)[0])
        scored.append((contacts, margin, n))
    if not scored:
        return None
    scored.sort(key=lambda x: (-x[0], -x[1]))
    return scored[0][2], scored[0][0], scored[0][1], (scored[1][0] if len(scored) > 1 else 0)


def standing_figure(P):
    """A standing figure (the longest principal extent over 2.2 times the next: a body, a
    statue): up along the long axis, towards its head: the end whose last tenth is one piece
    where the other is several (legs), else the end the head template fits better.
    (up, fit at the head end, fit at the other, certain, the template's front there) or None."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    c = P.mean(0)
    X = P - c
    w, E = np.linalg.eigh(X.T @ X)
    ext = np.array([np.ptp(X @ E[:, k]) for k in range(3)])
    order = np.argsort(ext)[::-1]
    if ext[order[0]] < 2.2 * ext[order[1]]:
        return None
    axis = E[:, order[0]]
    t = X @ axis
    fits, pieces, fronts = [], [], []
    for sgn in (1.0, -1.0):
        end = P[(sgn * t) >= (sgn * t).max() - 0.15 * np.ptp(t)]
        f = fit_head_template(end) if len(end) >= 100 else None
        fits.append(np.inf if f is None else f[3])
        fronts.append(None if f is None else f[0] @ np.array([0.0, 0.0, 1.0]))
        tip = P[(sgn * t) >= (sgn * t).max() - 0.10 * np.ptp(t)]
        G = cKDTree(tip).sparse_distance_matrix(cKDTree(tip), 0.04 * ext[order[0]], output_type="coo_matrix")
        pieces.append(int(connected_components(G, directed=False)[0]) if len(tip) else 0)
    if pieces[0] == 1 and pieces[1] >= 2:
        k, certain = 0, True
    elif pieces[1] == 1 and pieces[0] >= 2:
        k, certain = 1, True
    else:
        k = 0 if fits[0] <= fits[1] else 1
        certain = fits[k] <= 0.8 * fits[1 - k]
    up = axis if k == 0 else -axis
    return unit(up), float(fits[k]), float(fits[1 - k]), certain, fronts[k]
