"""Power diagrams of weighted points clipped to the unit square.

The power diagram of sites ``p_i`` with weights ``w_i`` gives each site the cell
``{x : |x - p_i|^2 - w_i <= |x - p_j|^2 - w_j for all j}``.  It is the vertical projection of
the lower convex hull of the lifted points ``(p_i, |p_i|^2 - w_i)`` (the regular
triangulation is that hull; the cells are its dual).  We compute the hull with Qhull through
SciPy, which is exact enough for well-separated points and degrades gracefully (a site it
cannot resolve gets an empty cell, never a crash).

How the square clipping is done, without mirroring every point:

* Four far *guard* sites with low weights close the diagram, so every real cell is bounded
  and no guard owns any part of the square.
* Interior pieces of the cell boundaries are the dual edges (segments between the power
  centres of adjacent triangles), clipped to the square (Liang–Barsky, vectorised).
* Pieces along the square's sides come from the exact 1D lower envelope of the sites' power
  functions on each side, computed only over the few sites whose cells can reach the side
  (those with a power centre on or outside the square).
* Areas and centroids follow from the shoelace formula over each cell's directed boundary
  pieces, taken relative to the site itself for precision (cells 1e-8 wide are common in
  conformal maps of heads).

Coordinates are re-centred on the square's centre before lifting.  Coincident points: one
keeps the cell and the others get empty cells (``area == 0``).

The regular triangulation itself, and its update by flips from a previous diagram's, is
:mod:`geoface.param.power_triangulation`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterizationError
from . import regular
from .power_triangulation import Triangulation, cgal_triangulation, exact_flips, flip_to_regular, qhull_triangulation

__all__ = ["PowerDiagram", "power_diagram", "BACKENDS"]

#: how a diagram is built from scratch: "auto" (CGAL when built, else Qhull), "cgal", "qhull"
BACKENDS = ("auto", "cgal", "qhull")

# the square's sides, counter-clockwise: start point and direction (unit length)
_SIDES = (
    (np.array([0.0, 0.0]), np.array([1.0, 0.0])),
    (np.array([1.0, 0.0]), np.array([0.0, 1.0])),
    (np.array([1.0, 1.0]), np.array([-1.0, 0.0])),
    (np.array([0.0, 1.0]), np.array([0.0, -1.0])),
)


@dataclass(frozen=True)
class PowerDiagram:
    """Power cells of ``n`` sites clipped to the unit square.

    Attributes
    ----------
    area : (n,) cell areas (they sum to 1; 0 for an empty cell)
    centroid : (n, 2) cell centroids (the site itself for an empty cell)
    edges : (k, 2) int64 pairs ``i < j`` of sites whose cells share a boundary segment
    edge_length : (k,) length of that segment inside the square
    """

    area: np.ndarray
    centroid: np.ndarray
    edges: np.ndarray
    edge_length: np.ndarray
    _tri: "Triangulation | None" = field(default=None, repr=False, compare=False)

    @property
    def empty(self) -> np.ndarray:
        return self.area <= 0.0

    @property
    def source(self) -> str:
        """What built the triangulation: ``"cgal"``, ``"qhull"`` or ``"flips"`` (an update)."""
        return self._tri.source if self._tri is not None else "trivial"


def _check(points, weights):
    P = np.asarray(points, np.float64)
    if P.ndim != 2 or P.shape[1] != 2:
        raise ParameterizationError(f"points must have shape (n, 2); got {P.shape}")
    n = len(P)
    w = np.zeros(n) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (n,):
        raise ParameterizationError(f"weights must have shape ({n},); got {w.shape}")
    if n == 0:
        raise ParameterizationError("power diagram of no points")
    if not (np.isfinite(P).all() and np.isfinite(w).all()):
        raise ParameterizationError("points or weights contain NaN or infinite values")
    if (P < -1.0).any() or (P > 2.0).any():
        raise ParameterizationError("points must lie near the unit square (within [-1, 2]^2)")
    return P, w


def _clip_segments(a, b, lo=-0.5, hi=0.5):
    """Liang–Barsky: parameters ``t0 <= t1`` of segments ``a + t (b - a)`` inside the square."""
    d = b - a
    t0 = np.zeros(len(a))
    t1 = np.ones(len(a))
    for k in range(2):
        dk = d[:, k]
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (lo - a[:, k]) / dk
            tb = (hi - a[:, k]) / dk
        tmin = np.minimum(ta, tb)
        tmax = np.maximum(ta, tb)
        par = dk == 0
        inside = (a[:, k] >= lo) & (a[:, k] <= hi)
        tmin = np.where(par, np.where(inside, -np.inf, np.inf), tmin)
        tmax = np.where(par, np.where(inside, np.inf, -np.inf), tmax)
        t0 = np.maximum(t0, tmin)
        t1 = np.minimum(t1, tmax)
    return t0, t1


def _lower_envelope(slope, icept):
    """Lower envelope of lines ``slope*t + icept`` over ``t`` in [0, 1].

    Returns (owners, breaks): owner k holds ``[breaks[k], breaks[k+1]]``.
    """
    order = np.lexsort((icept, -slope))  # slope descending, ties: lowest intercept first
    hull_m: list[float] = []
    hull_b: list[float] = []
    hull_i: list[int] = []
    last_m = None
    for idx in order:
        m, b = slope[idx], icept[idx]
        if last_m is not None and m == last_m:
            continue  # same slope, higher intercept: never below
        last_m = m
        while hull_m:
            # drop the last line when the new one takes over before it starts
            m1, b1 = hull_m[-1], hull_b[-1]
            x_new = (b - b1) / (m1 - m)  # where the new line meets the last one
            if len(hull_m) >= 2:
                m0, b0 = hull_m[-2], hull_b[-2]
                x_prev = (b1 - b0) / (m0 - m1)
            else:
                x_prev = -np.inf
            if x_new <= x_prev:
                hull_m.pop(); hull_b.pop(); hull_i.pop()
            else:
                break
        hull_m.append(m); hull_b.append(b); hull_i.append(int(idx))
    m = np.array(hull_m); b = np.array(hull_b)
    xs = (b[1:] - b[:-1]) / (m[:-1] - m[1:]) if len(m) > 1 else np.zeros(0)
    breaks = np.concatenate([[-np.inf], xs, [np.inf]])
    lo = np.clip(breaks[:-1], 0.0, 1.0)
    hi = np.clip(breaks[1:], 0.0, 1.0)
    keep = hi > lo
    owners = np.array(hull_i)[keep]
    return owners, np.concatenate([lo[keep], hi[keep][-1:]])


#: update a previous diagram's CGAL triangulation by compiled exact flips (False: build every
#: diagram anew, for tests and comparisons; both give the same regular triangulation).  On OT
#: problems of 1.2K-100K sites the flips cut the solve by 25-45%.
EXACT_FLIPS = True

#: sum the cells' interior pieces with the compiled extension when it has them (same arithmetic
#: as the NumPy path, 10-20x faster; False forces NumPy, for tests)
COMPILED_CELLS = True


def power_diagram(points, weights=None, *, previous: "PowerDiagram | None" = None, backend: str = "auto") -> PowerDiagram:
    """Power diagram of ``points (n, 2)`` with ``weights (n,)`` clipped to ``[0, 1]^2``.

    Sites may lie on the square's edges or slightly outside it; coincident sites get
    empty cells.  ``previous``: a diagram of the same points with other weights (a Newton
    step's last iterate): its regular triangulation is updated by Lawson flips (with CGAL: compiled,
    exact predicates, see :data:`EXACT_FLIPS`; with Qhull: vectorised NumPy), and a new one is
    built when flips cannot get there (a cell must vanish); a new CGAL triangulation reuses the
    previous one's insertion order.
    ``backend``: how a triangulation is built anew: ``"cgal"`` (exact predicates),
    ``"qhull"`` (SciPy; merges sites closer than ~1e-7) or ``"auto"`` (CGAL when built).
    The result's ``source`` says which built it.  Raises :class:`ParameterizationError` for
    malformed input.
    """
    if backend not in BACKENDS:
        raise ParameterizationError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if backend == "cgal":
        regular.require()
    P, w = _check(points, weights)
    n = len(P)
    X = P - 0.5  # re-centre: the square is [-0.5, 0.5]^2
    w = w - w.max()  # the diagram does not change; keeps the lifted heights small
    if n == 1:
        return PowerDiagram(np.ones(1), np.full((1, 2), 0.5), np.zeros((0, 2), np.int64), np.zeros(0))
    # guards: far enough and low enough never to own a point of the square
    rmax = float(np.abs(X).max())
    R = 3.0 + 4.0 * rmax
    imax = int(np.argmax(w))
    bound = (np.linalg.norm(X[imax]) + 0.7072) ** 2 - w[imax]
    w_guard = (R - 0.7072) ** 2 - bound - 1.0
    G = np.array([[R, 0.0], [0.0, R], [-R, 0.0], [0.0, -R]])
    Xa = np.concatenate([X, G])
    wa = np.concatenate([w, np.full(4, w_guard)])
    tri = None
    exact = backend == "cgal" or (backend == "auto" and regular.available())
    prev = previous._tri if previous is not None else None
    same = prev is not None and prev.X.shape == X.shape and np.array_equal(prev.X, X)
    if same and prev.updatable:
        if not exact:
            tri = flip_to_regular(prev, Xa, wa)
        elif EXACT_FLIPS:
            tri = exact_flips(prev, X, Xa, wa, n)
    if tri is None and exact:  # the sites' spatial order is sorted once per set of sites
        tri = cgal_triangulation(X, Xa, wa, n, prev.order if same else None)
    elif tri is None:
        tri = qhull_triangulation(X, Xa, wa, n)
    return _cells(X, w, Xa, n, tri)


def _interior(X, Xa, n, tri: Triangulation):
    """Area and first moment (relative to each site) of the cells' interior boundary pieces,
    and the shared edges with their lengths: the dual edges clipped to the square.  NumPy;
    :func:`geoface.param.regular.power_cells` is the same arithmetic compiled."""
    simp, nb, cen = tri.T, tri.N, tri.cen
    # dual edges: triangle t and its neighbour s opposite vertex k
    t_idx = np.repeat(np.arange(len(simp)), 3)
    k_idx = np.tile(np.arange(3), len(simp))
    s_idx = nb.ravel()
    sel = t_idx < s_idx
    t_idx, k_idx, s_idx = t_idx[sel], k_idx[sel], s_idx[sel]
    vi = simp[t_idx, (k_idx + 1) % 3]
    vj = simp[t_idx, (k_idx + 2) % 3]
    real = (vi < n) | (vj < n)
    vi, vj, t_idx, s_idx = vi[real], vj[real], t_idx[real], s_idx[real]
    a = cen[t_idx]
    b = cen[s_idx]
    t0, t1 = _clip_segments(a, b)
    inside = t1 > t0
    vi, vj, a, b, t0, t1 = vi[inside], vj[inside], a[inside], b[inside], t0[inside], t1[inside]
    d = b - a
    qa = a + t0[:, None] * d
    qb = a + t1[:, None] * d
    # orient each segment counter-clockwise around cell vi: outward normal (p_j - p_i)
    pij = Xa[vj] - Xa[vi]
    flip = (qb - qa)[:, 0] * pij[:, 1] - (qb - qa)[:, 1] * pij[:, 0] > 0  # want (q_b-q_a) . rot90(pij) > 0
    qa2 = np.where(flip[:, None], qb, qa)
    qb2 = np.where(flip[:, None], qa, qb)
    seg_len = np.linalg.norm(qb2 - qa2, axis=1)
    area = np.zeros(n)
    mom = np.zeros((n, 2))
    _shoelace(X, area, mom, vi, qa2, qb2)
    _shoelace(X, area, mom, vj, qb2, qa2)
    # (dual edges of cocircular quads have round-off length: no neighbours)
    both = (vi < n) & (vj < n) & (seg_len > 1e-15)
    e = np.sort(np.column_stack([vi[both], vj[both]]), axis=1)
    return area, mom, e, seg_len[both]


def _shoelace(X, area, mom, cell, pa, pb):
    """Add the directed pieces ``pa -> pb`` of cells ``cell`` (guards skipped) to ``area`` and
    ``mom``, relative to the sites ``X``."""
    n = len(area)
    keep = cell < n
    cell, pa, pb = cell[keep], pa[keep], pb[keep]
    r = X[cell]
    ra, rb = pa - r, pb - r
    cr = ra[:, 0] * rb[:, 1] - ra[:, 1] * rb[:, 0]
    area += np.bincount(cell, 0.5 * cr, minlength=n)
    s = cr / 6.0
    mom[:, 0] += np.bincount(cell, s * (ra[:, 0] + rb[:, 0]), minlength=n)
    mom[:, 1] += np.bincount(cell, s * (ra[:, 1] + rb[:, 1]), minlength=n)


def _sides(X, w, cand, area, mom):
    """The square's sides' part of the cells of sites ``cand``, added to ``area`` and ``mom``
    (NumPy; :func:`geoface.param.regular.power_sides` is the same arithmetic compiled)."""
    pieces_cell, pieces_a, pieces_b = [], [], []
    for A, dvec in _SIDES:
        A0 = A - 0.5
        diff = A0 - X[cand]
        slope = 2.0 * diff @ dvec
        icept = (diff * diff).sum(1) - w[cand]
        owners, br = _lower_envelope(slope, icept)
        pieces_cell.append(cand[owners])
        pieces_a.append(A0 + br[:-1, None] * dvec)
        pieces_b.append(A0 + br[1:, None] * dvec)
    _shoelace(X, area, mom, np.concatenate(pieces_cell), np.concatenate(pieces_a), np.concatenate(pieces_b))


def _cells(X, w, Xa, n, tri: Triangulation) -> PowerDiagram:
    simp, cen = tri.T, tri.cen
    native = regular.power_cells(n, Xa, tri.T, tri.N, cen) if COMPILED_CELLS else None
    area, mom, e, L = native if native is not None else _interior(X, Xa, n, tri)
    # the square's sides: sites with a power centre on or outside the square can reach them
    near = ~(np.abs(cen) < 0.5 - 1e-12).all(1)
    cand = np.unique(simp[near].ravel())
    cand = cand[cand < n]
    if len(cand) == 0:  # cannot happen for n >= 2 sites; be safe
        cand = np.arange(n)
    if not (COMPILED_CELLS and regular.power_sides(X, w, cand, area, mom)):
        _sides(X, w, cand, area, mom)

    area = np.maximum(area, 0.0)
    cent = X.copy()
    ok = area > 0
    cent[ok] = X[ok] + mom[ok] / area[ok, None]
    # shared edges between real sites: merge the duplicates of Qhull's triangulated coplanar
    # facets (in CGAL's triangulation, and its exact flips, each pair of sites shares at most one edge)
    if len(e) and not tri.exact:
        key = e[:, 0] * np.int64(n) + e[:, 1]
        uk, inv = np.unique(key, return_inverse=True)
        L = np.bincount(inv, L)
        e = np.column_stack([uk // n, uk % n])
    return PowerDiagram(area, np.clip(cent + 0.5, 0.0, 1.0), e.astype(np.int64).reshape(-1, 2), L, tri)
