"""The regular triangulation behind a power diagram (:mod:`geoface.param.power`): built anew
with Qhull or CGAL, or updated from a previous one by flips.

Newton's method for OT asks for many diagrams of the same sites with slowly changing weights:
``power_diagram(P, w, previous=pd)`` starts from ``pd``'s regular triangulation and restores
regularity by Lawson flips — compiled with CGAL's exact predicates behind a floating-point
filter (:func:`exact_flips`), or, for the Qhull backend, vectorised rounds over independent
sets of non-regular edges (:func:`flip_to_regular`).
Flips cannot delete a site: when one must vanish the update gets stuck on a non-convex quad and
the diagram is built anew.  Power centres come from each triangle's three sites (relative
to one of them), far more precise than Qhull's plane equations for cells 1e-6 wide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..errors import ParameterizationError
from . import regular


def _morton_order(X: np.ndarray) -> np.ndarray:
    """Z-order of 2D points (16 bits per axis): Qhull runs faster on spatially coherent input."""
    lo = X.min(0)
    q = ((X - lo) / max(float(np.ptp(X, 0).max()), 1e-300) * 65535).astype(np.uint64)

    def spread(x):
        for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
            x = (x | (x << np.uint64(shift))) & np.uint64(mask)
        return x

    return np.argsort(spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)), kind="stable")


@dataclass(frozen=True)
class Triangulation:
    """The regular triangulation behind a diagram: counter-clockwise triangles ``T`` over the
    sites and the four guards, ``N[t, k]`` the triangle across the edge opposite ``T[t, k]``
    (-1 on the guards' hull), and the power centres.  ``updatable``: every site is a vertex
    and no triangle is flat, so the next diagram can be reached by flips."""

    X: np.ndarray
    T: np.ndarray
    N: np.ndarray
    cen: np.ndarray
    updatable: bool
    source: str
    #: CGAL's insertion order (guards first, then the sites' spatial order), kept for the next
    #: diagram of the same sites
    order: np.ndarray | None = None
    #: built by CGAL or its exact flips: a proper triangulation, each pair of sites shares at most
    #: one edge (Qhull's triangulated coplanar facets can repeat one)
    exact: bool = False


def _orient(Xa, a, b, c):
    """Twice the signed area of triangles (a, b, c), coordinates relative to ``a``."""
    B = Xa[b] - Xa[a]
    C = Xa[c] - Xa[a]
    return B[:, 0] * C[:, 1] - B[:, 1] * C[:, 0]


def _power_incircle(Xa, wa, a, b, c, d):
    """(det, scale): det > 0 when ``d`` lies inside the power circle of counter-clockwise
    (a, b, c), i.e. its lifted point is below their plane and the edge it faces is not regular."""
    Xd = Xa[d]
    A, B, C = Xa[a] - Xd, Xa[b] - Xd, Xa[c] - Xd
    wd = wa[d]
    za = (A * A).sum(1) - (wa[a] - wd)
    zb = (B * B).sum(1) - (wa[b] - wd)
    zc = (C * C).sum(1) - (wa[c] - wd)
    bc = B[:, 0] * C[:, 1] - B[:, 1] * C[:, 0]
    ca = C[:, 0] * A[:, 1] - C[:, 1] * A[:, 0]
    ab = A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0]
    det = za * bc + zb * ca + zc * ab
    scale = np.abs(za * bc) + np.abs(zb * ca) + np.abs(zc * ab)
    return det, scale


def _power_centres(Xa, wa, T):
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    B = Xa[b] - Xa[a]
    C = Xa[c] - Xa[a]
    rb = (B * B).sum(1) - wa[b] + wa[a]
    rc = (C * C).sum(1) - wa[c] + wa[a]
    det = 2.0 * (B[:, 0] * C[:, 1] - B[:, 1] * C[:, 0])
    y = np.column_stack([rb * C[:, 1] - rc * B[:, 1], B[:, 0] * rc - C[:, 0] * rb]) / det[:, None]
    return Xa[a] + y


def qhull_triangulation(X, Xa, wa, n) -> Triangulation:
    lift = np.column_stack([Xa, (Xa * Xa).sum(1) - wa])
    order = np.concatenate([_morton_order(X), np.arange(n, n + 4)])
    try:
        hull = ConvexHull(lift[order], qhull_options="Qt")
    except QhullError as e:  # all points collinear etc.
        raise ParameterizationError(f"power diagram failed in Qhull: {str(e).splitlines()[0]}") from None
    eq = hull.equations
    lower = eq[:, 2] < -1e-12
    lid = np.full(len(eq), -1, np.int64)
    lid[lower] = np.arange(int(lower.sum()))
    T = order[hull.simplices[lower]].astype(np.int64)
    N = lid[hull.neighbors[lower]]
    o = _orient(Xa, T[:, 0], T[:, 1], T[:, 2])
    neg = o < 0
    T[neg] = T[neg][:, [0, 2, 1]]
    N[neg] = N[neg][:, [0, 2, 1]]
    # power centres from the three sites (a thousand times more precise for cells 1e-6
    # wide); flat triangles of coplanar facets take theirs from the facet plane:
    # z = 2 c.x + k  =>  c = -(nx, ny) / (2 nz)
    with np.errstate(divide="ignore", invalid="ignore"):
        cen = _power_centres(Xa, wa, T)
    flat = ~np.isfinite(cen).all(1)
    if flat.any():
        cen[flat] = -eq[lower][flat, :2] / (2.0 * eq[lower][flat, 2:3])
    present = np.bincount(T.ravel(), minlength=n + 4)[:n] > 0
    updatable = bool(present.all() and (np.abs(o) > 0).all())
    return Triangulation(X, T, N, cen, updatable, "qhull")


def cgal_triangulation(X, Xa, wa, n, order=None) -> Triangulation:
    """The regular triangulation with exact predicates (CGAL); every triangle is
    counter-clockwise and non-degenerate, hidden sites are simply absent.  ``order``: the
    insertion order of an earlier diagram of the same sites (computed here when None)."""
    if order is None:
        order = regular.spatial_order(Xa, first=np.arange(n, len(Xa)))
    T, N = regular.regular_triangulation(Xa, wa, order)
    return _exact(X, Xa, wa, n, T, N, "cgal", order)


def exact_flips(prev: Triangulation, X, Xa, wa, n) -> Triangulation | None:
    """The previous diagram's regular triangulation flipped to the new weights (compiled, exact
    predicates): a Newton step moves few edges, and flipping them costs a tenth of building the
    triangulation anew.  None when the flips cannot get there (a site must disappear) or the
    extension predates them."""
    got = regular.flip_to_regular(Xa, wa, prev.T, prev.N)
    return None if got is None else _exact(X, Xa, wa, n, got[0], got[1], "flips", prev.order)


def _exact(X, Xa, wa, n, T, N, source, order) -> Triangulation:
    """A Triangulation of exact-predicate triangles ``T``, ``N``: their power centres."""
    with np.errstate(divide="ignore", invalid="ignore"):
        compiled = regular.power_centres(Xa, wa, T)
        cen, n_flat = compiled if compiled is not None else (_power_centres(Xa, wa, T), None)
    flat = ~np.isfinite(cen).all(1)
    if flat.any():  # a triangle too thin for double precision: extended precision
        cen[flat] = _power_centres(Xa.astype(np.longdouble), wa.astype(np.longdouble), T[flat]).astype(np.float64)
        cen[~np.isfinite(cen).all(1)] = Xa[T[~np.isfinite(cen).all(1), 0]]
    if n_flat is None:
        n_flat = int((_orient(Xa, T[:, 0], T[:, 1], T[:, 2]) <= 0).sum())
    present = np.bincount(T.ravel(), minlength=n + 4)[:n] > 0
    updatable = bool(present.all() and n_flat == 0)
    return Triangulation(X, T, N, cen, updatable, source, order, exact=True)


#: a non-regular edge is flipped when its power in-circle determinant exceeds this share of
#: its magnitude (near-degenerate quads are left as they are: their dual edge has no length)
_FLIP_TOL = 1e-11
_MAX_ROUNDS = 2000


def flip_to_regular(prev: Triangulation, Xa, wa) -> Triangulation | None:
    """Lawson flips from the previous regular triangulation to the one of the new weights.

    Rounds of simultaneous flips over an independent set of non-regular edges (Luby's rule
    on random priorities: no two flips touch the same triangle or its neighbours).  Returns
    ``None`` when it gets stuck — a non-regular edge whose quad is not convex, which is how a
    site that must disappear shows itself — and the caller falls back to Qhull.
    """
    T = prev.T.copy()
    N = prev.N.copy()
    m = len(T)
    rng = np.random.default_rng(12345)
    t, k = np.nonzero(N > np.arange(m)[:, None])
    for _ in range(_MAX_ROUNDS):
        if len(t) == 0:
            break
        s = N[t, k]
        j = np.argmax(N[s] == t[:, None], axis=1)
        c, a, b = T[t, k], T[t, (k + 1) % 3], T[t, (k + 2) % 3]
        d = T[s, j]
        det, scale = _power_incircle(Xa, wa, c, a, b, d)
        bad = det > _FLIP_TOL * scale
        if not bad.any():
            break
        t, k, s, j, a, b, c, d = (x[bad] for x in (t, k, s, j, a, b, c, d))
        convex = (_orient(Xa, c, a, d) > 0) & (_orient(Xa, d, b, c) > 0)
        if not convex.any():
            return None
        ft, fk, fs, fj, fa, fb, fc, fd = (x[convex] for x in (t, k, s, j, a, b, c, d))
        # independent set: each flip claims its two triangles and their neighbours
        pri = rng.random(len(ft))
        claim = np.column_stack([ft, fs, N[ft], N[fs]])
        valid = claim >= 0
        best = np.full(m, -1.0)
        np.maximum.at(best, claim[valid], np.broadcast_to(pri[:, None], claim.shape)[valid])
        win = np.where(valid, best[np.where(valid, claim, 0)] == pri[:, None], True).all(1)
        ft, fk, fs, fj, fa, fb, fc, fd = (x[win] for x in (ft, fk, fs, fj, fa, fb, fc, fd))
        t_a = N[ft, (fk + 1) % 3]
        t_b = N[ft, (fk + 2) % 3]
        s_b = N[fs, (fj + 1) % 3]
        s_a = N[fs, (fj + 2) % 3]
        T[ft] = np.column_stack([fc, fa, fd])
        N[ft] = np.column_stack([s_b, fs, t_b])
        T[fs] = np.column_stack([fd, fb, fc])
        N[fs] = np.column_stack([t_a, ft, s_a])
        for outer, old, new in ((t_a, ft, fs), (s_b, fs, ft)):
            sel = outer >= 0
            o, ol, nw = outer[sel], old[sel], new[sel]
            col = np.argmax(N[o] == ol[:, None], axis=1)
            N[o, col] = nw
        # next candidates: the unflipped bad edges and the four outer edges of each flip
        keep = ~np.isin(t, ft) & ~np.isin(t, fs)
        ct = np.concatenate([t[keep], ft, ft, fs, fs])
        ck = np.concatenate([k[keep], np.zeros(len(ft), np.int64), np.full(len(ft), 2), np.zeros(len(fs), np.int64), np.full(len(fs), 2)])
        cs = N[ct, ck]
        inner = cs >= 0
        ct, ck, cs = ct[inner], ck[inner], cs[inner]
        # canonical side: the lower triangle index
        swap = cs < ct
        cj = np.argmax(N[cs] == ct[:, None], axis=1)
        ct, ck = np.where(swap, cs, ct), np.where(swap, cj, ck)
        key = np.unique(ct * 3 + ck)
        t, k = key // 3, key % 3
    else:
        return None
    if (_orient(Xa, T[:, 0], T[:, 1], T[:, 2]) <= 0).any():
        return None
    return Triangulation(prev.X, T, N, _power_centres(Xa, wa, T), True, "flips", prev.order)
