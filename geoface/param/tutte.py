"""Fold-free starts for the solvers that need one: Tutte's embedding of a disk with its boundary
on the square, and a map made fold-free where it folds (:func:`fold_free_start`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..mesh.core import signed_uv_areas
from .foldfree import convex_combination_map, disk_loop

__all__ = ["fold_free_start", "square_boundary", "tutte_map"]


def square_boundary(loop: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Positions on the unit square's perimeter for the boundary ``loop``, in order along it: the
    four loop vertices nearest the square's corners go to the corners and the vertices between
    two of them are spaced evenly along that side. A convex polygon in the loop's order, whatever
    order ``uv`` itself keeps along the boundary."""
    P = uv[loop]
    if float(np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])) < 0:
        loop_rev = True
        P = P[::-1]
    else:
        loop_rev = False
    k = len(P)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    c0 = int(np.argmin(np.linalg.norm(P - square[0], axis=1)))
    order = (np.arange(k) + c0) % k  # the loop from the (0, 0) corner on, counter-clockwise
    rel = [0] + [int(np.argmin(np.linalg.norm(P[order] - square[s], axis=1))) for s in (1, 2, 3)]
    if not (0 < rel[1] < rel[2] < rel[3] < k):  # corners out of order: four equal runs instead
        rel = [0, k // 4, k // 2, (3 * k) // 4]
    out = np.empty((k, 2))
    bounds = rel + [k]
    for s in range(4):
        a, b = bounds[s], bounds[s + 1]
        f = (np.arange(a, b) - a) / max(b - a, 1)
        out[order[a:b]] = square[s] + f[:, None] * (square[(s + 1) % 4] - square[s])
    return out[::-1] if loop_rev else out


def tutte_map(F, uv) -> np.ndarray:
    """Tutte's embedding of the disk ``F``: the boundary on the unit square as
    :func:`square_boundary` puts it (``uv``'s own boundary positions where those are already in
    order along the loop), every interior vertex the mean of its neighbours. Fold-free for a
    convex boundary polygon (Tutte 1963; Floater 2003), whatever ``uv`` does."""
    F = np.asarray(F, np.int64)
    uv = np.asarray(uv, np.float64)
    n = len(uv)
    loop = disk_loop(F, "a Tutte embedding")
    inner = np.ones(n, bool)
    inner[loop] = False
    i, j = np.concatenate([F[:, [0, 1, 2]].ravel(), F[:, [1, 2, 0]].ravel()]), \
        np.concatenate([F[:, [1, 2, 0]].ravel(), F[:, [0, 1, 2]].ravel()])
    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    A.data[:] = 1.0  # each edge once, whatever its number of faces
    I_idx, O_idx = np.flatnonzero(inner), np.flatnonzero(~inner)
    deg = np.asarray(A.sum(1)).ravel()
    L = (sp.diags(deg) - A).tocsr()  # deg x_i - sum of the neighbours = 0 inside
    x = uv.copy()
    x[loop] = square_boundary(loop, uv)
    if len(I_idx):
        rhs = -(L[I_idx][:, O_idx] @ x[O_idx])
        x[I_idx] = spla.splu(L[I_idx][:, I_idx].tocsc(), permc_spec="COLAMD").solve(np.ascontiguousarray(rhs))
    return x


def fold_free_start(F, uv) -> np.ndarray:
    """``uv`` itself when it does not fold, else a fold-free map equal to it away from its folds
    (:func:`convex_combination_map` with :func:`tutte_map` as the reference): a start for
    the solvers that need one (``geoface.param.balance.area_balanced_map``). A conformal map
    laid out through intrinsic flips can fold where its chords cross (a point cloud's Poisson
    surface with handles cut, e.g.), though the conformal map itself does not."""
    F = np.asarray(F, np.int64)
    uv = np.asarray(uv, np.float64)
    a = signed_uv_areas(F, uv)
    orient = 1.0 if a.sum() >= 0 else -1.0
    if not (orient * a <= 0).any():
        return uv
    return convex_combination_map(F, uv, tutte_map(F, uv)).uv
