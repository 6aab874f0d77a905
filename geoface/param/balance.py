"""An area-balanced embedding of a disk in the unit square: fold-free at every step, whatever
the range of the conformal factor.

Optimal transport places its sites at the vertices of a starting map.  On the conformal map of
a head with long protrusions, fins or slivers, neighbouring sites can sit 1e-9 apart while
their cells must grow a billion-fold: the power diagram's cells then react to changes of the
heights below what double precision resolves, and Newton's method cannot be damped.  Sites
whose spacing matches their target masses do not have that problem.  This module makes such
sites, with linear algebra only:

A *convex-combination map* (Tutte; Floater 2003) puts every interior vertex at a positive
combination ``x_i = Σ_j λ_ij x_j`` of its neighbours, the boundary in order on the square: it
is one-to-one for any positive weights.  With the mean value coordinates of the conformal map
as weights it reproduces the conformal map.  Each round then scales the weights towards every
neighbour ``j`` by ``ρ_j^η``, with ``ρ_j = a_j / ν_j`` the ratio of vertex ``j``'s share of the
square (⅓ of its triangles' UV area) to its target mass: a vertex whose region is too small
pulls its neighbours less, so they move away and the region grows; the boundary's spacing along
each side is scaled the same way, by ``ρ^{-η}``.  The reweighting is the stretch-minimising
iteration of Yoshizawa, Belyaev & Seidel (2004) driven by area instead of stretch.  It works
on ratios, so a region a billion times too small expands as readily as one twice too small;
every iterate is fold-free (checked exactly), and the best iterate (smallest worst log ratio)
is returned.  It does not converge to an exact measure-preserving map (the worst vertices
oscillate within a factor of about e^3): optimal transport from these sites finishes the job.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ParameterizationError
from ..mesh.core import signed_uv_areas, uv_vertex_areas
from .foldfree import along_side, boundary_sides, disk_loop, loop_area, mean_value_weights, on_side

__all__ = ["BalancedMap", "area_balanced_map", "log_area_ratio"]

#: reweighting exponent (η above) and the iteration's stopping rules
ETA = 0.5
TARGET_LOG = 1.5
MAX_ROUNDS = 40
PATIENCE = 8


@dataclass(frozen=True)
class BalancedMap:
    """uv : (n, 2) the best iterate (fold-free); max_log_ratio / mean_log_ratio : worst and mean
    |log(a_i / ν_i)| of it; start_max_log_ratio : of the starting map; rounds : reweighting
    rounds run; best_round : the round ``uv`` comes from (0: the starting map); history : the
    worst |log ratio| of every round."""

    uv: np.ndarray
    max_log_ratio: float
    mean_log_ratio: float
    start_max_log_ratio: float
    rounds: int
    best_round: int
    history: list = field(default_factory=list)


def log_area_ratio(F: np.ndarray, uv: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """``log(a_i / ν_i)`` per vertex: its share of the map's area (⅓ of its triangles) over its
    share of the target masses."""
    a = uv_vertex_areas(F, uv)
    a = a / a.sum()
    return np.log(np.maximum(a, 1e-300) / (nu / nu.sum()))


def _boundary_layout(loop, start, ratio, spacing, eta):
    """Boundary positions: each side's gaps scaled by ``ρ^{-η}`` of their end vertices and
    renormalised to the side; corners stay.  ``spacing``: the current gaps (updated in place)."""
    side, f0 = start
    out = np.empty((len(loop), 2))
    k = len(loop)
    g = (ratio[loop] * ratio[loop[np.r_[1:k, 0]]]) ** (-0.5 * eta)
    spacing *= g
    for s in range(4):
        run = side == s
        idx = np.flatnonzero(run)
        # the side's vertices in loop order, from its first corner (f0 == 0)
        first = idx[np.argmin(f0[idx])]
        order = [(first + i) % k for i in range(len(idx))]
        gaps = spacing[order]  # gap i: from order[i] to the next loop vertex
        cum = np.concatenate([[0.0], np.cumsum(gaps)])
        pos = cum[:-1] / cum[-1]
        out[order] = on_side(pos, np.full(len(order), s))
    return out


def area_balanced_map(F, uv, nu, *, target_log: float = TARGET_LOG, max_rounds: int = MAX_ROUNDS, eta: float = ETA,
                      patience: int = PATIENCE) -> BalancedMap:
    """An area-balanced, fold-free map of the disk ``F`` onto the unit square, from the fold-free
    map ``uv`` (boundary on the square's sides, four vertices at its corners) and target masses
    ``nu`` (see the module's description).  Stops when the worst ``|log(a_i / ν_i)|`` is at most
    ``target_log``, after ``max_rounds`` rounds, or when ``patience`` rounds bring no improvement."""
    F = np.asarray(F, np.int64)
    uv = np.asarray(uv, np.float64)
    nu = np.asarray(nu, np.float64)
    n = len(uv)
    loop = disk_loop(F, "an area-balanced map")
    if nu.shape != (n,) or not (np.isfinite(nu).all() and (nu > 0).all()):
        raise ParameterizationError(f"nu must be ({n},) positive masses")
    a0 = signed_uv_areas(F, uv)
    orient = 1.0 if a0.sum() >= 0 else -1.0
    if (orient * a0 < 0).any():
        raise ParameterizationError("the starting map must not fold")
    side, corner = boundary_sides(uv[loop], "the starting map")
    f0 = np.where(corner, 0.0, along_side(uv[loop], side))
    if loop_area(uv[loop]) < 0:  # walk the loop counter-clockwise in the square
        loop, side, f0 = loop[::-1], side[::-1], f0[::-1]
        corner = corner[::-1]
    nxt = np.r_[1 : len(loop), 0]
    spacing = np.linalg.norm(uv[loop[nxt]] - uv[loop], axis=1)
    inner = np.ones(n, bool)
    inner[loop] = False
    I_idx = np.flatnonzero(inner)
    W, good = mean_value_weights(F, uv, n, orient)
    W = W.tocoo()
    rows, cols = W.row, W.col
    keep = inner[rows]
    rows, cols = rows[keep], cols[keep]
    # the starting map's own weights (positive on a fold-free map); uniform where they are not
    vals = np.where(good[rows] & (W.data[keep] > 0), W.data[keep], 0.0)
    bad_rows = np.zeros(n, bool)
    np.logical_or.at(bad_rows, rows, vals <= 0)
    vals = np.where(bad_rows[rows], 1.0, vals)
    vals = vals / np.bincount(rows, vals, minlength=n)[rows]
    pos_in = np.full(n, -1)
    pos_in[I_idx] = np.arange(len(I_idx))
    inner_col = inner[cols]
    r = log_area_ratio(F, uv, nu)
    best = (float(np.abs(r).max()), 0, uv.copy(), r)
    history = [best[0]]
    start = best[0]
    x = uv.copy()
    stale = 0
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        if best[0] <= target_log:
            break
        ratio = np.exp(np.clip(r, -40.0, 40.0))
        vals = vals * ratio[cols] ** eta
        vals = vals / np.bincount(rows, vals, minlength=n)[rows]
        xb = _boundary_layout(loop, (side, f0), ratio, spacing, eta)
        A = sp.coo_matrix((-vals[inner_col], (pos_in[rows[inner_col]], pos_in[cols[inner_col]])),
                          shape=(len(I_idx), len(I_idx))).tocsc() + sp.identity(len(I_idx), format="csc")
        bsel = ~inner_col
        xfull = x.copy()
        xfull[loop] = xb
        rhs = np.zeros((len(I_idx), 2))
        np.add.at(rhs, pos_in[rows[bsel]], vals[bsel, None] * xfull[cols[bsel]])
        try:
            xi = spla.splu(A, permc_spec="COLAMD").solve(rhs)
        except RuntimeError:  # numerically singular (weights underflowed): stop with the best so far
            break
        xn = xfull.copy()
        xn[I_idx] = xi
        if not np.isfinite(xn).all() or (orient * signed_uv_areas(F, xn) <= 0).any():
            break  # rounding made a triangle flat: keep the best fold-free iterate
        x = xn
        r = log_area_ratio(F, x, nu)
        worst = float(np.abs(r).max())
        history.append(worst)
        if worst < best[0]:
            best, stale = (worst, rounds, x.copy(), r), 0
        else:
            stale += 1
            if stale >= patience:
                break
    return BalancedMap(uv=best[2], max_log_ratio=best[0], mean_log_ratio=float(np.abs(best[3]).mean()),
                       start_max_log_ratio=start, rounds=rounds, best_round=best[1], history=history)
