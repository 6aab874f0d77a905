"""Fold-free maps onto the unit square by construction: convex-combination maps whose
weights reproduce a target map wherever the target is itself fold-free.

Tutte's theorem, in the form of Floater (2003, "One-to-one piecewise linear mappings over
triangulations"): map the boundary of a triangulated disk in order onto a convex polygon and
put every interior vertex at a strictly convex combination of its neighbours,

    x_i = Σ_j λ_ij x_j,     λ_ij > 0,   Σ_j λ_ij = 1,                    (1)

then the piecewise-linear map is one-to-one (no triangle is flipped or flat) as long as no
edge joins two vertices on the same straight side.  The system (1) has one solution for
any positive weights, so this step cannot fail.

The weights are Floater's mean value coordinates (MVC) of a target map ``c`` (the
optimal-transport centroids): at an interior vertex whose triangles are all positively
oriented in ``c``,

    λ_ij ∝ (tan(α_ij⁻ / 2) + tan(α_ij⁺ / 2)) / |c_j - c_i|                (2)

(α± the angles at ``c_i`` of the two triangles on edge ij) is positive and reproduces
``c_i`` exactly, so where the target has no fold the solution of (1) *is* the target.
Around a fold (a vertex with a non-positive angle in ``c``) MVC are not positive; there
the weights are the positive ones that put ``c_i`` closest to the same combination of its
neighbours' targets,

    λ_i = argmin_{λ ∈ Δ} |Σ_j λ_j (c_j - c_i)|² + μ_i |λ - λ_i^ref|²          (3)

(Δ the simplex; a small μ_i ties the choice, among the many exact ones, to the mean value
coordinates of a fold-free reference map such as the conformal map), mixed with a little of
``λ^ref`` so that every weight is strictly positive.  A vertex inside the convex hull of
its neighbours' targets is then reproduced almost exactly; one outside goes to the nearest
point of that hull.  The boundary keeps the target's positions, made strictly monotone along
each side when they are not.

Solving (1) for all vertices is a sparse LU of the whole mesh.  Since the target reproduces
itself away from the folds, the vertices within a few rings of the folds are solved first
with the others held at the target; that map is kept when it has no fold (which is checked
exactly, triangle by triangle), and otherwise the whole system is solved, which cannot fold.

>>> import numpy as np
>>> from geoface.synth import square_grid
>>> V, F = square_grid(6)
>>> uv = V[:, :2].copy()
>>> r = convex_combination_map(F, uv, uv)
>>> r.flipped, float(np.abs(r.uv - uv).max()) < 1e-12
(0, True)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ParameterizationError
from ..mesh.core import boundary_loops, signed_uv_areas
from .untangle import area_loss, untangle

__all__ = ["FoldFreeResult", "convex_combination_map", "disk_loop", "mean_value_weights", "square_sides"]

#: a target angle at a vertex must exceed this (radians) for the vertex to keep its own MVC
MIN_ANGLE = 1e-9
#: the untangled map replaces the whole system's solve when that loses this many times more of
#: the target's areas (mean |log| of the vertex-area ratios): only where the whole solve
#: collapses a region. On male02 at 512² one corner set's whole solve loses 10.7× the untangled
#: map's (a limb squeezed into a strip: 15.4% Hausdorff against 0.65%); below about 2× the whole
#: solve's smoother triangles reconstruct better (spot with sliver strips: 0.2–0.5% against
#: 0.5–1.1% untangled at ratios 1.5–2.1), and one male02 set at 1.9× goes the other way
UNTANGLE_GAIN = 3.0
#: … and only tried when the whole solve loses more than this (mean |log| area ratio; the
#: untangled maps measured lose 0.23 and more, so below it the gain cannot reach 3×)
UNTANGLE_MIN_LOSS = 0.6
#: the local solve: rings of vertices around the folds, and the largest share of the interior
LOCAL_RINGS = (8, 32)
LOCAL_SHARE = 0.3
#: with ``refine`` (the untangled map's slivers relaxed towards the masses, as the OT step does),
#: the untangled map is tried once the whole solve loses more than this of the wanted areas and
#: kept whenever it loses less. The 134K bust's whole solve loses 0.12–0.13 (kept: whole Hausdorff
#: 0.14–0.18% at 512² against 0.34–0.45% relaxed, although the relaxed map loses only 0.03);
#: male02's whole solves at 512² leave 0.27–15.4% Hausdorff (a limb squeezed into a strip in
#: set 0; untangled and relaxed, as kept in all 8: 0.38% at worst,
#: ``bench/results/stress/male02_untangle_512.jsonl``); the Max Planck bust cut
#: to 1K faces loses 0.29–0.38 (relaxed: worst face 0.17% against 0.37%, the whole solve
#: squeezing the jaw's few large triangles to a pixel)
REFINED_GAIN = 1.0
REFINED_MIN_LOSS = 0.2


@dataclass(frozen=True)
class FoldFreeResult:
    """uv : (n, 2) the fold-free map; flipped : non-positive triangles of it (0);
    target_flipped : non-positive triangles of the target; fitted_vertices : interior
    vertices whose weights were fitted by (3) (around the target's folds);
    boundary_adjusted : boundary vertices moved to keep each side monotone;
    max_displacement : max |uv - target|; rounds : global solves (0 when the local solve
    sufficed; more than 1 if rounding flipped a triangle and the weights there were made
    uniform); solve : ``"local"`` (only the vertices near the folds moved: the map had no
    fold, so it was kept), ``"untangled"`` (the local solve folded; the folds were undone
    vertex by vertex, :func:`untangle`) or ``"global"`` (the whole system (1): fold-free by
    Tutte's theorem); solved_vertices : how many vertices the kept solve placed."""

    uv: np.ndarray
    flipped: int
    target_flipped: int
    fitted_vertices: int
    boundary_adjusted: int
    max_displacement: float
    rounds: int
    solve: str = "global"
    solved_vertices: int = 0


def disk_loop(F: np.ndarray, what: str) -> np.ndarray:
    """The one boundary loop of the disk ``F``; ``what`` needs a disk and says so otherwise."""
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"{what} needs a disk (one boundary loop); got {len(loops)}")
    return loops[0]


def square_sides(uv: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """(n, 4) bool: which sides of the unit square each point lies on (x=0, x=1, y=0, y=1)."""
    return np.column_stack([uv[:, 0] <= eps, uv[:, 0] >= 1 - eps, uv[:, 1] <= eps, uv[:, 1] >= 1 - eps])


def _corner_angles(F, uv, orient):
    """Signed angle at each corner of each triangle, (m, 3), positive for a triangle that is
    oriented like the map (``orient``)."""
    P = uv[F]
    out = np.empty(F.shape)
    for k in range(3):
        a = P[:, (k + 1) % 3] - P[:, k]
        b = P[:, (k + 2) % 3] - P[:, k]
        cr = orient * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        out[:, k] = np.arctan2(cr, (a * b).sum(1))
    return out


def mean_value_weights(F: np.ndarray, uv: np.ndarray, n: int, orient: float = 1.0) -> tuple[sp.csr_matrix, np.ndarray]:
    """Mean value coordinates (2) of every vertex with respect to its neighbours in ``uv``.

    Returns the ``(n, n)`` matrix of unnormalised weights and ``good (n,)``: every angle at
    the vertex lies in (MIN_ANGLE, π) and they sum to 2π or less (so the vertex's weights
    are positive; an interior vertex with all of them is reproduced exactly).
    """
    ang = _corner_angles(F, uv, orient)
    t = np.tan(0.5 * np.clip(ang, -np.pi, np.pi))
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, l = F[:, k], F[:, (k + 1) % 3], F[:, (k + 2) % 3]
        for other in (j, l):
            r = np.linalg.norm(uv[other] - uv[i], axis=1)
            rows.append(i)
            cols.append(other)
            vals.append(t[:, k] / np.maximum(r, 1e-300))
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    bad = np.zeros(n, bool)
    np.logical_or.at(bad, F.ravel(), ((ang <= MIN_ANGLE) | (ang >= np.pi)).ravel())
    total = np.bincount(F.ravel(), np.abs(ang).ravel(), minlength=n)
    bad |= total > 2 * np.pi + 1e-6
    bad |= np.asarray((W < 0).sum(1)).ravel() > 0
    return W, ~bad


def _isotonic(y: np.ndarray) -> np.ndarray:
    """Least-squares non-decreasing fit (pool adjacent violators)."""
    vals: list = []
    wts: list = []
    for v in y.tolist():
        vals.append(v)
        wts.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            w = wts[-2] + wts[-1]
            vals[-2:] = [(vals[-2] * wts[-2] + vals[-1] * wts[-1]) / w]
            wts[-2:] = [w]
    return np.repeat(vals, wts)


def _side_index(p: np.ndarray) -> np.ndarray:
    """One side per point on the square's boundary (0 bottom, 1 right, 2 top, 3 left,
    counter-clockwise); a corner takes the side that leaves it counter-clockwise."""
    x0, x1, y0, y1 = square_sides(p).T
    idx = np.full(len(p), -1)
    idx[x0] = 3
    idx[y1] = 2
    idx[x1] = 1
    idx[y0] = 0
    idx[x0 & y0], idx[x1 & y0], idx[x1 & y1], idx[x0 & y1] = 0, 1, 2, 3
    return idx


def along_side(p: np.ndarray, side: np.ndarray) -> np.ndarray:
    """Fraction along each point's side, counter-clockwise (0 at the side's first corner)."""
    return np.select([side == 0, side == 1, side == 2], [p[:, 0], p[:, 1], 1.0 - p[:, 0]], 1.0 - p[:, 1])


def on_side(f: np.ndarray, side: np.ndarray) -> np.ndarray:
    return np.select([side[:, None] == 0, side[:, None] == 1, side[:, None] == 2],
                     [np.column_stack([f, 0 * f]), np.column_stack([1 + 0 * f, f]), np.column_stack([1.0 - f, 1 + 0 * f])],
                     np.column_stack([0 * f, 1.0 - f]))


def loop_area(p: np.ndarray) -> float:
    q = np.roll(p, -1, axis=0)
    return 0.5 * float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum())


def boundary_sides(p: np.ndarray, what: str = "the map") -> tuple[np.ndarray, np.ndarray]:
    """The side (0 bottom, 1 right, 2 top, 3 left) of each boundary point ``p`` of a map onto the
    square and which four are its corners; :class:`ParameterizationError` unless every point is on
    a side and exactly four are at the corners."""
    side = _side_index(p)
    if (side < 0).any():
        raise ParameterizationError(f"{what} must put every boundary vertex on the square's sides")
    s = square_sides(p)
    corner = s[:, :2].any(1) & s[:, 2:].any(1)
    if corner.sum() != 4:
        raise ParameterizationError(f"{what} must put 4 boundary vertices at the square's corners; got {int(corner.sum())}")
    return side, corner


def _monotone_boundary(loop: np.ndarray, target: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, int]:
    """Boundary positions on the square: ``target``'s, with the corners and sides of ``ref``,
    made strictly increasing along each side (counter-clockwise) where they are not.
    Returns (positions (k, 2) in loop order, number of vertices moved)."""
    side, corner = boundary_sides(ref[loop], "the reference map")
    f = np.clip(along_side(target[loop], side), 0.0, 1.0)
    f[corner] = 0.0
    order = np.arange(len(loop)) if loop_area(ref[loop]) > 0 else np.arange(len(loop))[::-1]
    start = np.flatnonzero(corner[order] & (side[order] == 0))[0]
    order = np.roll(order, -start)  # counter-clockwise from the corner at (0, 0)
    moved = 0
    for k in range(4):
        run = order[(side[order] == k) & ~corner[order]]
        if len(run) == 0:
            continue
        seg = f[run]
        if not (np.diff(np.concatenate([[0.0], seg, [1.0]])) > 0).all():
            fit = np.clip(_isotonic(seg), 0.0, 1.0)
            uniform = np.arange(1, len(seg) + 1) / (len(seg) + 1)
            new = (1.0 - 1e-3) * fit + 1e-3 * uniform  # strictly increasing, inside (0, 1)
            moved += int((new != seg).sum())
            f[run] = new
    return on_side(f, side), moved


def _project_simplex(v: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Rows of ``v`` projected onto the probability simplex over their ``valid`` entries."""
    v = np.where(valid, v, -1e300)
    u = -np.sort(-v, axis=1)
    css = np.cumsum(np.where(u > -1e299, u, 0.0), axis=1) - 1.0
    k = np.arange(1, v.shape[1] + 1)
    cond = (u - css / k > 0) & (u > -1e299)
    r = cond.shape[1] - 1 - np.argmax(cond[:, ::-1], axis=1)
    theta = css[np.arange(len(v)), r] / (r + 1)
    return np.where(valid, np.maximum(v - theta[:, None], 0.0), 0.0)


def _fitted_weights(rows: np.ndarray, target: np.ndarray, W_ref: sp.csr_matrix, *, iterations: int = 400,
                    mu: float = 1e-3, mix: float = 1e-3) -> sp.csr_matrix:
    """Weights (3) for the vertices ``rows`` (FISTA on the simplex, all rows at once);
    returned as an ``(n, n)`` matrix with rows summing to 1 (other rows empty)."""
    n = len(target)
    if len(rows) == 0:
        return sp.csr_matrix((n, n))
    indptr, indices = W_ref.indptr, W_ref.indices
    deg = indptr[rows + 1] - indptr[rows]
    K = int(deg.max())
    col = np.arange(K)[None, :]
    valid = col < deg[:, None]
    pos = np.where(valid, indptr[rows][:, None] + col, 0)
    nb = np.where(valid, indices[pos], 0)
    ref = np.where(valid, np.maximum(W_ref.data[pos], 0.0), 0.0)
    ref_sum = ref.sum(1, keepdims=True)
    ref = np.where(ref_sum > 0, ref / np.where(ref_sum > 0, ref_sum, 1.0), valid / deg[:, None])
    D = np.where(valid[:, :, None], target[nb] - target[rows][:, None, :], 0.0)  # (b, K, 2)
    s2 = (D * D).sum(2)
    scale = np.maximum(s2.sum(1) / deg, 1e-300)  # mean squared neighbour distance
    m = mu * scale
    L = 2.0 * (s2.sum(1) + m)  # >= the gradient's Lipschitz constant (trace bound)
    lam = ref.copy()
    y = lam.copy()
    t = 1.0
    for _ in range(iterations):
        r = np.einsum("bk,bkd->bd", y, D)
        g = 2.0 * np.einsum("bkd,bd->bk", D, r) + 2.0 * m[:, None] * (y - ref)
        new = _project_simplex(y - g / L[:, None], valid)
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        y = new + ((t - 1.0) / t_new) * (new - lam)
        lam, t = new, t_new
    lam = (1.0 - mix) * lam + mix * ref  # strictly positive
    lam = lam / lam.sum(1, keepdims=True)
    r_idx = np.repeat(rows, K).reshape(-1, K)
    return sp.csr_matrix((lam[valid], (r_idx[valid], nb[valid])), shape=(n, n))


def convex_combination_map(F, target, reference, *, max_rounds: int = 4, refine=None, score=None) -> FoldFreeResult:
    """A fold-free map of the disk ``F`` onto the unit square that equals ``target`` where
    ``target`` has no folds (see module docs).

    Parameters
    ----------
    F : (m, 3) int64 — a triangulated disk, no edge joining two vertices of one side
    target : (n, 2) — the wanted map (e.g. optimal-transport centroids), boundary vertices on
        the square's sides; it may fold
    reference : (n, 2) — a fold-free map onto the unit square with the same corners (e.g. the
        conformal map): its weights are used around the target's folds
    max_rounds : extra solves allowed when floating-point rounding leaves a triangle
        non-positive (weights there become uniform; in exact arithmetic one solve suffices)
    refine : optional ``uv -> uv``, fold-free in and out: applied to an untangled map before it
        is compared with the whole solve (:func:`geoface.param.relax.relax_map`)
    score : optional ``uv -> float``, how much of the wanted areas a map loses (default: mean
        |log| of the vertex-area ratios against ``target``'s, :func:`area_loss`)
    """
    F = np.asarray(F, np.int64)
    target = np.asarray(target, np.float64)
    reference = np.asarray(reference, np.float64)
    n = len(target)
    if target.shape != (n, 2) or reference.shape != (n, 2):
        raise ParameterizationError(f"target and reference must be ({n}, 2) arrays")
    if not (np.isfinite(target).all() and np.isfinite(reference).all()):
        raise ParameterizationError("target and reference must be finite")
    loop = disk_loop(F, "a convex-combination map")
    a_ref = signed_uv_areas(F, reference)
    orient = 1.0 if a_ref.sum() >= 0 else -1.0
    if (orient * a_ref < 0).any():
        raise ParameterizationError("the reference map must not fold")
    target_flipped = int((orient * signed_uv_areas(F, target) <= 0).sum())
    inner = np.ones(n, bool)
    inner[loop] = False
    # boundary: on the square, strictly monotone along each side
    xb, moved = _monotone_boundary(loop, target, reference)
    W_t, good_t = mean_value_weights(F, target, n, orient)
    W_r, _ = mean_value_weights(F, reference, n, orient)
    W_r.data = np.maximum(W_r.data, 0.0)
    use_ref = inner & ~good_t
    # rows: own MVC where the target is fine there, fitted weights (3) elsewhere
    W_fit = _fitted_weights(np.flatnonzero(use_ref), target, W_r)
    W = (sp.diags(np.where(use_ref, 0.0, 1.0)) @ W_t + W_fit).tocsr()
    x = target.copy()
    x[loop] = xb
    target_b = x.copy()
    A_graph = (abs(W_t) + abs(W_r)).tocsr()
    A_graph.data[:] = 1.0
    Lam = _normalised(W, inner, A_graph)
    # first a solve near the folds only (the rest kept at the target, which reproduces itself
    # there); it is kept when it has no fold, else the whole system (1) is solved
    moved_b = np.zeros(n, bool)
    moved_b[loop[np.any(xb != target[loop], axis=1)]] = True
    seed = use_ref.copy()
    seed[F[orient * signed_uv_areas(F, target) <= 0].ravel()] = True
    seed |= moved_b
    solve = "global"
    rounds = 0
    region = seed.copy()
    grown = 0
    for rings in LOCAL_RINGS:
        for _ in range(rings - grown):
            region |= np.asarray(A_graph @ region.astype(float)).ravel() > 0
        grown = rings
        r_in = region & inner
        if not 0 < r_in.sum() <= LOCAL_SHARE * inner.sum():
            break
        xl = x.copy()
        xl[r_in] = _solve(Lam, r_in, xl)
        if not (orient * signed_uv_areas(F, xl) <= 0).any():
            x, solve, region = xl, "local", r_in
            break
    if solve == "global" and not (orient * signed_uv_areas(F, x) <= 0).any():
        solve, region = "local", np.zeros(n, bool)  # nothing to solve: the target is fold-free
    if solve == "global":
        uniform = np.zeros(n, bool)
        for rounds in range(1, max_rounds + 2):
            L_r = Lam if not uniform.any() else _normalised(W, inner, A_graph, uniform)
            x[inner] = _solve(L_r, inner, x)
            bad = orient * signed_uv_areas(F, x) <= 0
            if not bad.any():
                break
            # rounding flipped a near-degenerate triangle: uniform (Tutte) weights around it
            ring = np.zeros(n, bool)
            ring[F[bad].ravel()] = True
            ring |= np.asarray(A_graph @ ring.astype(float)).ravel() > 0
            uniform |= ring & inner
    loss = score if score is not None else (lambda y: area_loss(F, y, target))
    if solve == "global" and (whole := loss(x)) > (UNTANGLE_MIN_LOSS if refine is None else REFINED_MIN_LOSS):
        # the whole solve lost much of the target's areas: the folds untangled near where they
        # are instead, if that keeps far more (where the folds are many the whole solve can squeeze
        # a region that the reference map shrank, a limb, back into a strip)
        xu, ok = untangle(F, target_b, inner, orient)
        if ok:
            gain = UNTANGLE_GAIN
            if refine is not None:  # the untangled map's slivers relaxed: compared as it is
                xu, gain = refine(xu), REFINED_GAIN
            local = loss(xu)
            logging.getLogger("geoface").debug("fold-free step: the whole solve loses %.3g of the target's areas, "
                                               "the untangled map %.3g", whole, local)
            if whole > gain * local:
                x, solve, region = xu, "untangled", np.any(xu != target, axis=1)
    elif solve == "untangled" and refine is not None:
        x = refine(x)
    flipped = int((orient * signed_uv_areas(F, x) <= 0).sum())
    if flipped:
        raise ParameterizationError(f"internal: {flipped} triangles of a convex-combination map are not positive "
                                    "(floating-point rounding on near-degenerate triangles)")
    return FoldFreeResult(
        uv=x, flipped=0, target_flipped=target_flipped, fitted_vertices=int(use_ref.sum()),
        boundary_adjusted=moved, max_displacement=float(np.abs(x - target).max()), rounds=rounds, solve=solve,
        solved_vertices=int(region.sum() if solve != "global" else inner.sum()),
    )


def _normalised(W: sp.csr_matrix, inner: np.ndarray, A_graph: sp.csr_matrix, uniform: np.ndarray | None = None) -> sp.csr_matrix:
    """Rows of (1) normalised to sum 1; rows in ``uniform`` (and rows with no positive
    weight, around flat reference triangles) get uniform weights."""
    n = W.shape[0]
    u = np.zeros(n, bool) if uniform is None else uniform.copy()
    rs = np.asarray(W.sum(1)).ravel()
    u |= inner & (rs <= 0)
    Wr = W
    if u.any():
        Wr = (sp.diags(np.where(u, 0.0, 1.0)) @ W + sp.diags(np.where(u, 1.0, 0.0)) @ A_graph).tocsr()
        rs = np.asarray(Wr.sum(1)).ravel()
    return (sp.diags(1.0 / np.where(rs > 0, rs, 1.0)) @ Wr).tocsr()


def _solve(Lam: sp.csr_matrix, rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Positions of the vertices ``rows`` from (1), the others held at ``x``."""
    I_idx = np.flatnonzero(rows)
    O_idx = np.flatnonzero(~rows)
    L_I = Lam[I_idx]
    A = sp.identity(len(I_idx), format="csc") - L_I[:, I_idx].tocsc()
    rhs = L_I[:, O_idx] @ x[O_idx]
    return spla.splu(A, permc_spec="COLAMD").solve(np.ascontiguousarray(rhs))

