"""Relaxing a fold-free map back towards the measure-preserving one, without ever folding.

The optimal-transport centroids ``c`` can fold a few triangles; the fold-free step
(:mod:`geoface.param.foldfree`) removes the folds, but where it solves the whole
convex-combination system it moves every vertex, and a limb that the conformal map shrank can
come back squeezed into a strip (on male02 the mean |log| area error grows from 0.3 to 1.0).
:func:`relax_map` starts from that fold-free map ``x⁰`` and minimises

    E(x) = Σ_t T_t φ(A_t(x) / T_t) + κ/2 Σ_i |x_i − c_i|²,     φ(r) = r − 1 − log r,

over the interior vertices (the boundary stays where it is): ``A_t`` the signed areas of the
map, ``T_t`` the areas the target masses give each triangle (its 3D area times the mean
density ν_k / (3D vertex area)_k of its corners, scaled to the square) and κ the weight of the
pull towards the centroids (moving a vertex by one of its edges, |d|² ≈ 2 T, costs about as
much as halving a triangle's area).  φ is a barrier: it is
infinite at zero area, so a descent that never lets a triangle reach zero area keeps the map
fold-free.  Every step is limited to 90% of the largest step at which a triangle's signed area
(a quadratic in the step length) reaches zero, so no iterate folds; the result is checked
exactly once more and replaced by ``x⁰`` if any triangle is not positive.  Where the centroid
map has no fold both terms pull towards it (its triangles have about their target areas);
around the folds the barrier holds the triangles open.
"""

from __future__ import annotations

import numpy as np

from ..mesh.core import face_areas, signed_uv_areas, vertex_areas

__all__ = ["relax_map", "triangle_targets"]

#: the pull towards the centroid map, relative to the area barrier
KAPPA = 0.1
#: the fraction of the step to a zero area that a step may take
MAX_FRACTION = 0.9
#: stop once the last STALL_WINDOW steps took off less than STALL_GAIN of the energy
STALL_WINDOW = 10
STALL_GAIN = 0.01


def triangle_targets(V: np.ndarray, F: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Target map areas per triangle from vertex masses ``nu``: 3D area times the mean
    density of its corners, summing to 1 (the unit square)."""
    va = vertex_areas(V, F)
    dens = np.asarray(nu, np.float64) / np.maximum(va, 1e-300)
    T = face_areas(V, F) * dens[F].mean(1)
    T = np.maximum(T, 1e-12 * T.max())
    return T / T.sum()


def _max_step(F, x, d, A):
    """The largest α ≥ 0 for which every A_t(x + α d) stays positive (∞ if none reaches zero)."""
    a, b = x[F[:, 1]] - x[F[:, 0]], x[F[:, 2]] - x[F[:, 0]]
    da, db = d[F[:, 1]] - d[F[:, 0]], d[F[:, 2]] - d[F[:, 0]]
    B = 0.5 * (da[:, 0] * b[:, 1] - da[:, 1] * b[:, 0] + a[:, 0] * db[:, 1] - a[:, 1] * db[:, 0])
    C = 0.5 * (da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0])
    # roots of A + B α + C α² = 0 with α > 0
    alpha = np.full(len(A), np.inf)
    lin = np.abs(C) <= 1e-14 * (np.abs(B) + np.abs(A))
    m = lin & (B < 0)
    alpha[m] = -A[m] / B[m]
    q = ~lin
    disc = B[q] ** 2 - 4.0 * C[q] * A[q]
    ok = disc >= 0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    # numerically stable roots
    qq = -0.5 * (B[q] + np.copysign(sq, B[q]))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(qq != 0, qq / C[q], np.inf)
        r2 = np.where(qq != 0, A[q] / qq, np.inf)
    r1 = np.where(ok & (r1 > 0), r1, np.inf)
    r2 = np.where(ok & (r2 > 0), r2, np.inf)
    alpha[q] = np.minimum(r1, r2)
    return float(alpha.min()) if len(alpha) else np.inf


def _area_jacobian(F, x, orient, col):
    """The (m, 2k) sparse Jacobian of the signed areas (times ``orient``) with respect to the
    movable vertices' coordinates; ``col[v]`` is vertex v's column pair (-1: fixed)."""
    import scipy.sparse as sp

    m = len(F)
    rows, cols, vals = [], [], []
    for k in range(3):
        p, q = x[F[:, (k + 1) % 3]], x[F[:, (k + 2) % 3]]
        c = col[F[:, k]]
        ok = c >= 0
        t = np.flatnonzero(ok)
        rows += [t, t]
        cols += [2 * c[ok], 2 * c[ok] + 1]
        vals += [0.5 * orient * (p[ok, 1] - q[ok, 1]), 0.5 * orient * (q[ok, 0] - p[ok, 0])]
    k2 = int(col.max()) + 1
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, 2 * k2))


def relax_map(F, x0, target, T, *, movable=None, orient: float = 1.0, kappa: float = KAPPA,
              max_iterations: int = 150, rel_tol: float = 1e-6, linear_solver: str = "auto") -> tuple[np.ndarray, dict]:
    """Relax the fold-free map ``x0`` towards the centroid map ``target`` (module docs).

    Parameters
    ----------
    F : (m, 3) triangles; x0 : (n, 2) a map with every triangle positive (times ``orient``)
    target : (n, 2) the wanted positions (may fold); T : (m,) target triangle areas (scaled to
        the map's total; see :func:`triangle_targets`)
    movable : (n,) bool, the vertices that may move (default: all)

    Gauss-Newton steps (the Hessian of the barrier without its indefinite part, plus κ I),
    each cut to 90% of the step at which a triangle would reach zero area, then halved until
    the energy decreases enough (Armijo).  Returns ``(x, info)``: ``x`` fold-free (``x0``
    itself if ``x0`` was not), info with the iterations and the energy before and after.
    """
    import scipy.sparse as sp

    from .linsolve import SPDSolver

    F = np.asarray(F, np.int64)
    x = np.array(x0, np.float64, copy=True)
    c = np.asarray(target, np.float64)
    n = len(x)
    mov = np.ones(n, bool) if movable is None else np.asarray(movable, bool)
    A = orient * signed_uv_areas(F, x)
    info = {"iterations": 0, "energy_before": None, "energy_after": None, "kept": False}
    if not (A > 0).all() or not mov.any():
        return x, info
    T = np.asarray(T, np.float64) * (A.sum() / np.asarray(T, np.float64).sum())
    idx = np.flatnonzero(mov)
    col = np.full(n, -1, np.int64)
    col[idx] = np.arange(len(idx))
    reg = kappa * sp.identity(2 * len(idx), format="csr")
    solver = SPDSolver(linear_solver)

    def energy(y, A):
        r = A / T
        if (r <= 0).any():
            return np.inf
        return float(np.sum(T * (r - 1.0 - np.log(r))) + 0.5 * kappa * np.sum((y[idx] - c[idx]) ** 2))

    e = energy(x, A)
    info["energy_before"] = e
    history = [e]
    for it in range(1, max_iterations + 1):
        J = _area_jacobian(F, x, orient, col)
        g = J.T @ (1.0 - T / A) + kappa * (x[idx] - c[idx]).ravel()
        # the barrier's curvature T/A², capped so that no triangle adds more than 1e10 κ to the
        # diagonal (a tiny triangle otherwise puts 1e30 beside 1: no factorization survives that)
        gn2 = np.asarray(J.multiply(J).sum(1)).ravel()
        with np.errstate(over="ignore", divide="ignore"):
            D = np.minimum(T / A**2, 1e10 * kappa / np.maximum(gn2, 1e-300))
        H = (J.T @ sp.diags(D) @ J + reg).tocsc()
        d = np.zeros_like(x)
        try:
            d[idx] = -solver.solve(H, g).reshape(-1, 2)
        except Exception:  # a factorization that rounding broke: the gradient step instead
            d[idx] = -(g / kappa).reshape(-1, 2)
        slope = float(g @ d[idx].ravel())
        if not slope < 0:
            break
        step = min(1.0, MAX_FRACTION * _max_step(F, x, d, A))
        accepted = False
        while step > 1e-10:
            xn = x + step * d
            An = orient * signed_uv_areas(F, xn)
            en = energy(xn, An)
            if en <= e + 1e-4 * step * slope:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            break
        de = e - en
        x, A, e = xn, An, en
        history.append(e)
        info["iterations"] = it
        if de <= rel_tol * max(abs(e), 1e-300):
            break
        if len(history) > STALL_WINDOW and history[-STALL_WINDOW - 1] - e < STALL_GAIN * history[-STALL_WINDOW - 1]:
            break  # crawling: steps held short by triangles about to close gain little more
    info["energy_after"] = e
    if not (orient * signed_uv_areas(F, x) > 0).all():  # cannot happen with the step limit; checked anyway
        return np.array(x0, np.float64, copy=True), info
    info["kept"] = True
    return x, info
