"""Untangling a folded planar map near its folds, the vertices there moved together by L-BFGS on
a penalty of non-positive triangle areas (:func:`untangle`), and how much of a target map's
areas a map loses (:func:`area_loss`): the local alternative that the fold-free step
(:func:`geoface.param.foldfree.convex_combination_map`) takes where solving the whole
convex-combination system would collapse a region."""

from __future__ import annotations

import numpy as np

from ..mesh.core import signed_uv_areas, uv_vertex_areas, vertex_adjacency

__all__ = ["untangle", "area_loss"]


def area_loss(F: np.ndarray, uv: np.ndarray, target: np.ndarray) -> float:
    """Mean |log(a_i / t_i)| of the vertices' areas (⅓ of the adjacent triangles' absolute
    areas, normalised) in ``uv`` against those in ``target``."""
    def va(p):
        v = uv_vertex_areas(F, p)
        return v / max(v.sum(), 1e-300)

    a, t = va(uv), va(target)
    ok = t > 0
    return float(np.mean(np.abs(np.log(np.maximum(a[ok], 1e-300) / t[ok]))))


#: :func:`untangle` stops a region's L-BFGS once its energy has dropped by less than ``STALL`` (a
#: share of itself) over the last ``STALL_WINDOW`` iterations
STALL = 0.01
STALL_WINDOW = 100


def untangle(F: np.ndarray, x: np.ndarray, movable: np.ndarray, orient: float = 1.0, *,
             rings=(2, 8, 32, None), max_iterations: int = 3000) -> tuple[np.ndarray, bool]:
    """Untangle a folded map near its folds: the ``movable`` vertices within a few rings of the
    non-positive triangles (``None``: all of them) move together, the rest stay put, to minimise

        Σ_t (max(0, ε − A_t) / ε)² + w Σ_i |x_i − x_i⁰|² / ε

    (A_t the triangles' signed areas, ε a tenth of their median area, w = 1e-3), by L-BFGS until
    the energy stalls (:data:`STALL`); the region grows until no triangle is non-positive
    (checked exactly). A whole flipped patch
    untangles (the penalty moves its vertices together) and every triangle keeps about its
    area, where a convex-combination solve with a conformal reference can squeeze a region that
    the conformal map shrank (a limb) back into a strip. Returns ``(uv, fold-free?)``."""
    from scipy.optimize import minimize

    x0 = np.array(x, np.float64, copy=True)
    F = np.asarray(F, np.int64)
    n = len(x0)
    A0 = orient * signed_uv_areas(F, x0)
    bad = A0 <= 0
    if not bad.any():
        return x0, True
    eps = 0.1 * float(np.median(np.abs(A0)))
    if not eps > 0:
        return x0, False
    nbr = vertex_adjacency(F, n)
    region = np.zeros(n, bool)
    region[F[bad].ravel()] = True
    grown, w, last = 0, 1e-3, -1
    for k in rings:
        if k is None:
            region = movable.copy()
        else:
            for _ in range(k - grown):
                region |= np.asarray(nbr @ region.astype(float)).ravel() > 0
            grown = k
        free = np.flatnonzero(region & movable)
        if len(free) == 0 or len(free) == last:
            continue
        last = len(free)
        Ft = F[np.isin(F, free).any(1)]
        where = np.full(n, len(free))  # fixed vertices: a dummy row, dropped
        where[free] = np.arange(len(free))
        idx = where[Ft]

        def energy(z, Ft=Ft, idx=idx, free=free):
            y = x0.copy()
            y[free] = z.reshape(-1, 2)
            a, b, c = y[Ft[:, 0]], y[Ft[:, 1]], y[Ft[:, 2]]
            A = orient * signed_uv_areas(Ft, y)
            h = np.maximum(0.0, eps - A) / eps
            d = y[free] - x0[free]
            gA = -h / eps * orient  # dE/d(area2) = dE/dA · ½ · orient
            # d area2 / d p for (p, q, r) in cyclic order: (q_y − r_y, r_x − q_x)
            gx = np.concatenate([(b[:, 1] - c[:, 1]), (c[:, 1] - a[:, 1]), (a[:, 1] - b[:, 1])]) * np.tile(gA, 3)
            gy = np.concatenate([(c[:, 0] - b[:, 0]), (a[:, 0] - c[:, 0]), (b[:, 0] - a[:, 0])]) * np.tile(gA, 3)
            rows = idx.T.ravel()
            g = np.stack([np.bincount(rows, gx, len(free) + 1)[:-1], np.bincount(rows, gy, len(free) + 1)[:-1]], 1)
            grad = g + 2.0 * w * d / eps
            return float((h * h).sum() + w * (d * d).sum() / eps), grad.ravel()

        seen: list = []  # a new list per region: the closure below reads this one

        def stalled(intermediate_result):  # scipy passes the state to a parameter of this name
            """Stop once the energy has dropped by less than :data:`STALL` of itself over the last
            :data:`STALL_WINDOW` iterations: a region that untangles sits at its balance of area
            penalty and displacement by then, and one that cannot has stopped trying (L-BFGS's
            own tolerances, kept tight, would run every call to ``max_iterations``)."""
            seen.append(float(intermediate_result.fun))
            k = len(seen)
            if k > STALL_WINDOW and k % 10 == 0 and seen[-STALL_WINDOW - 1] - seen[-1] <= STALL * abs(seen[-STALL_WINDOW - 1]):
                raise StopIteration

        z = minimize(energy, x0[free].ravel(), jac=True, method="L-BFGS-B", callback=stalled,
                     options={"maxiter": int(max_iterations), "gtol": 1e-12, "ftol": 1e-15}).x
        y = x0.copy()
        y[free] = z.reshape(-1, 2)
        if not (orient * signed_uv_areas(F, y) <= 0).any():
            return y, True
    return x0, False
