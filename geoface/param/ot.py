"""Semi-discrete optimal transport and the measure-preserving map (Zhao et al. 2013).

Transport the uniform measure on the unit square Ω to points ``p_i`` carrying masses
``ν_i`` (``Σ ν = 1 = |Ω|``).  The heights ``h`` define the power diagram with weights ``h``;
the convex energy ``E(h) = ∫_Ω min_i(|x - p_i|² - h_i) dx + Σ h_i ν_i`` (up to sign) has

* gradient ``w_i(h) - ν_i`` where ``w_i`` is the area of cell ``i`` (eq. 7), and
* Hessian ``∂w_i/∂h_j = -|e_ij| / (2 |p_i - p_j|)`` for neighbouring cells, with the
  diagonal making rows sum to zero (eq. 8; ``|e_ij|`` is the shared edge's length).

Newton's method with the damping rule of Kitagawa, Mérigot and Thibert (2019): take the full
step, halve it while any cell is smaller than ``ε₀ = ½ min(min w(h₀), min ν)`` or the residual
does not fall by the factor ``1 - τ/2``.  The residual is measured relative to each target,
``‖(w - ν) / ν‖``: a Newton step shrinks every component alike, and a cell 1e-16 of the
square would otherwise be judged against round-off in the areas of cells 1e-3 large.  This converges globally.  The gauge is fixed by
``Σ h = 0``.  Convergence: ``max |w_i - ν_i| / ν_i ≤ tol`` (default 1e-3).

Conformal maps of real scans give sites whose masses and local spacings span many orders
of magnitude (cells 1e-16 of the square that must grow to 1e-4); reaching ``ν`` straight
from ``h = 0`` then costs many halvings.  ``continuation`` (on by default) walks the target
from the cells' starting areas to ``ν`` in stages geometric in log space, each warm-started
from the last, so every stage takes nearly full Newton steps.

Precision: power diagrams use exact predicates (:mod:`geoface.param.regular`), and each
Newton direction gets two steps of iterative refinement with the Hessian applied to
differences (a cluster of sites moves as one by ~1e-9 while its cells need differences of
~1e-20).  Sites of real scans' conformal maps 2e-8 apart converge; clusters of random sites
1e-9 apart whose cells must grow 1e18-fold are beyond double precision (the heights ``h``
would have to be resolved to 1e-25) and raise :class:`ParameterizationError`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import ParameterizationError
from ..progress import log
from .linsolve import SPDSolver
from .power import PowerDiagram, power_diagram

__all__ = ["OTResult", "semi_discrete_ot", "transport_hessian"]

#: continuation: the largest change of log target mass per stage, and the tolerance of a
#: stage before the last
STAGE_LOG_STEP = 1.0
STAGE_TOL = 1.0
#: steps of iterative refinement of each Newton direction
REFINEMENT_STEPS = 2
#: inexact Newton: conjugate gradients preconditioned by the last factorisation (5-20% faster
#: than a factorisation per step from 1.5K sites, 2x on the 134K bust); they stop when the
#: relative linear residual is PCG_RTOL of the Newton residual, or give up after
#: PCG_MAX_ITERATIONS (then the Hessian is factorised anew, as it is at the next step after
#: PCG_REFACTOR_AFTER iterations); False: a factorisation every step
REUSE_FACTOR = True
PCG_RTOL = 1e-3
PCG_MAX_ITERATIONS = 20
PCG_REFACTOR_AFTER = 12


@dataclass(frozen=True)
class OTResult:
    """Result of :func:`semi_discrete_ot`.

    h : (n,) heights (Σ h = 0); area : (n,) cell areas; centroid : (n, 2) cell centroids;
    nu : (n,) the target masses (normalised); residual : max |w - ν| / ν;
    iterations : Newton steps; halvings : step halvings; merged : sites that coincide with
    another site and share its cell (their centroid is the shared cell's); backend : what
    built the first power diagram (``"cgal"``: exact predicates, or ``"qhull"``).
    """

    h: np.ndarray
    area: np.ndarray
    centroid: np.ndarray
    nu: np.ndarray
    residual: float
    converged: bool
    iterations: int
    halvings: int
    seconds: float
    stages: int = 1
    merged: int = 0
    history: list = field(default_factory=list)
    backend: str = "cgal"
    gradient_steps: int = 0
    factorizations: int = 0
    pcg_iterations: int = 0
    failure: str = ""
    stage_reached: int = 0


def _hessian_weights(points: np.ndarray, pd: PowerDiagram) -> np.ndarray:
    """``|e_ij| / (2 |p_i - p_j|)`` for the diagram's edges (eq. 8)."""
    e = pd.edges
    d = np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1)
    return pd.edge_length / (2.0 * np.maximum(d, 1e-300))


def _apply_hessian(e: np.ndarray, c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``H x`` as ``Σ_j c_ij (x_i - x_j)``: differences first, so a vector with a large common
    part (a cluster's shared height) keeps the precision of its differences."""
    t = c * (x[e[:, 0]] - x[e[:, 1]])
    n = len(x)
    return np.bincount(e[:, 0], t, minlength=n) - np.bincount(e[:, 1], t, minlength=n)


def transport_hessian(points: np.ndarray, pd: PowerDiagram, weights: np.ndarray | None = None) -> sp.csr_matrix:
    """The Jacobian ``∂w/∂h`` (eq. 8), a weighted graph Laplacian (``weights``: the edges'
    ``|e_ij| / (2 |p_i - p_j|)`` when the caller has them)."""
    n = len(points)
    e = pd.edges
    c = _hessian_weights(points, pd) if weights is None else weights
    H = sp.coo_matrix((np.concatenate([-c, -c]), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n)).tocsr()
    H = H + sp.diags(np.asarray(-H.sum(1)).ravel())
    return H.tocsr()


def _pcg(solver, e, c, free, g, target):
    """``(d, iterations)``: the Newton direction (``H d = -g`` on the free sites, ``d = 0`` at the
    pinned one) by conjugate gradients preconditioned with ``solver``'s last factorisation, or
    None when they do not converge in :data:`PCG_MAX_ITERATIONS`.  Residuals are measured
    relative to the target masses, as the damping rule measures them; ``H`` is applied to
    differences (:func:`_apply_hessian`), which keeps clustered sites' precision."""
    n = len(g)
    x = np.zeros(n)
    r = -g[free]
    tf = target[free]
    stop = PCG_RTOL * float(np.linalg.norm(g / target))
    z = solver.resolve(r)
    p = z.copy()
    rz = float(r @ z)
    for it in range(PCG_MAX_ITERATIONS):
        q = np.zeros(n)
        q[free] = p
        Ap = _apply_hessian(e, c, q)[free]
        pAp = float(p @ Ap)
        if not (pAp > 0) or not np.isfinite(pAp):
            return None, it + 1
        alpha = rz / pAp
        x[free] += alpha * p
        r -= alpha * Ap
        if float(np.linalg.norm(r / tf)) <= stop:
            return x, it + 1
        z = solver.resolve(r)
        rz_new = float(r @ z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return None, PCG_MAX_ITERATIONS


def _hessian_diagonal(e: np.ndarray, c: np.ndarray, n: int) -> np.ndarray:
    """The diagonal of :func:`transport_hessian`: each site's ``Σ_j c_ij``."""
    return np.bincount(e[:, 0], c, minlength=n) + np.bincount(e[:, 1], c, minlength=n)


def _free_hessian(e: np.ndarray, c: np.ndarray, free: np.ndarray) -> sp.csc_matrix:
    """``H[free][:, free]`` of :func:`transport_hessian` built directly (CSC, sorted)."""
    n = len(free)
    index = np.cumsum(free) - 1
    diag = _hessian_diagonal(e, c, n)
    both = free[e[:, 0]] & free[e[:, 1]]
    i, j, cb = index[e[both, 0]], index[e[both, 1]], c[both]
    k = np.flatnonzero(free)
    m = len(k)
    rows = np.concatenate([i, j, np.arange(m)])
    cols = np.concatenate([j, i, np.arange(m)])
    vals = np.concatenate([-cb, -cb, diag[k]])
    return sp.csc_matrix((vals, (rows, cols)), shape=(m, m))


def _rel_residual(area, nu):
    return float(np.max(np.abs(area - nu) / nu))


def _merge_coincident(P: np.ndarray, nu: np.ndarray, h: np.ndarray, backend: str):
    """Sites with no cell at the start (coincident points; with Qhull also sites closer than
    it resolves) join the site owning their position; returns ``rep`` (site ->
    representative) and the reduced problem."""
    pd = power_diagram(P, h, backend=backend)
    empty = pd.area <= 0
    rep = np.arange(len(P))
    if empty.any():
        alive = np.flatnonzero(~empty)
        _, j = cKDTree(P[alive]).query(P[empty])
        rep[empty] = alive[j]
    keep = np.flatnonzero(rep == np.arange(len(P)))
    index = np.full(len(P), -1)
    index[keep] = np.arange(len(keep))
    red = index[rep]
    nu_r = np.bincount(red, nu, minlength=len(keep))
    return red, keep, nu_r, (pd if not empty.any() else None)


def semi_discrete_ot(
    points,
    masses=None,
    *,
    tol: float = 1e-3,
    max_iterations: int = 300,
    h0=None,
    continuation: bool = True,
    linear_solver: str = "auto",
    backend: str = "auto",
    stall: int = 0,
    min_step: float = 1e-9,
    partial: bool = False,
    quiet: bool | None = None,
) -> OTResult:
    """Heights ``h`` whose power cells in the unit square have areas ``masses`` (normalised).

    Parameters
    ----------
    points : (n, 2) sites in [0, 1]^2
    masses : (n,) positive target masses (default uniform); normalised to sum 1
    tol : stop when ``max |w_i - ν_i| / ν_i <= tol``
    h0 : warm start (e.g. the heights of a previous, similar problem)
    continuation : reach the target through intermediate targets (see module docs)
    backend : how power diagrams are built anew: ``"cgal"`` (exact predicates), ``"qhull"``
        or ``"auto"`` (CGAL when built); see :func:`geoface.param.power.power_diagram`
    stall : give up (:class:`ParameterizationError`) after this many steps in a row of at most
        1/64 of the Newton step: a solve that will not converge fails fast, so that the caller
        can try better sites (0: never)
    min_step : the smallest damping tried before the diagonally scaled gradient is (a step
        along ``-g / diag(H)``, judged by the same rule); when that fails too, the solve gives up
    partial : on giving up, return the last accepted state (``converged`` False, ``failure``
        saying why) instead of raising: its centroids are a map between the sites and the target,
        from which a caller can start again

    Raises
    ------
    ParameterizationError
        When the step cannot be damped: sites so crowded that their cells react to the heights
        below double precision (``measure_preserving_map`` then moves the sites), or a stall.
    """
    t_start = time.perf_counter()
    P = np.asarray(points, np.float64)
    if P.ndim != 2 or P.shape[1] != 2:
        raise ParameterizationError(f"points must have shape (n, 2); got {P.shape}")
    n = len(P)
    nu = np.full(n, 1.0 / n) if masses is None else np.asarray(masses, np.float64)
    if nu.shape != (n,):
        raise ParameterizationError(f"masses must have shape ({n},); got {nu.shape}")
    if not np.isfinite(nu).all() or (nu <= 0).any():
        raise ParameterizationError("masses must be finite and positive")
    if not (tol > 0):
        raise ParameterizationError(f"tol must be positive; got {tol}")
    nu = nu / nu.sum()
    h = np.zeros(n) if h0 is None else np.asarray(h0, np.float64).copy()
    if h.shape != (n,) or not np.isfinite(h).all():
        raise ParameterizationError(f"h0 must be a finite ({n},) array")
    red, keep, nu_r, pd = _merge_coincident(P, nu, h, backend)
    Pr = P[keep]
    hr = h[keep] - h[keep].mean()
    if pd is None:
        pd = power_diagram(Pr, hr, backend=backend)
    built = pd.source
    if (pd.area <= 0).any():
        raise ParameterizationError(f"{int((pd.area <= 0).sum())} sites have empty cells at the start even after merging "
                                    f"coincident sites ({built} triangulation)")
    solver = SPDSolver(linear_solver, ordering="amd", mode="simplicial")
    # a Newton direction is first sought by conjugate gradients preconditioned with the last
    # factorisation (far cheaper than a new one when the Hessian has changed little); a new
    # factorisation when they do not converge (REUSE_FACTOR)
    factorizations = pcg_iterations = 0
    refactor = False
    # each trial diagram is the last accepted one's triangulation flipped to the new heights
    # (compiled, exact); built anew when flips cannot get there (a cell would vanish)
    # gauge: pin the site with the largest starting cell (re-centred after every step)
    free = np.ones(len(Pr), bool)
    free[int(np.argmax(pd.area))] = False
    history: list = []
    iterations = halvings = gradient_steps = short = 0
    failure, stage_reached = "", 0
    # stages: targets between the starting areas and nu, geometric in log space
    w0 = pd.area
    spread = float(np.max(np.abs(np.log(nu_r / w0))))
    n_stages = 1
    if continuation and spread > STAGE_LOG_STEP:
        n_stages = int(np.ceil(spread / STAGE_LOG_STEP))
    converged = False
    res = _rel_residual(pd.area, nu_r)
    for stage in range(1, n_stages + 1):
        s = stage / n_stages
        target = np.exp((1 - s) * np.log(w0) + s * np.log(nu_r))
        target = target / target.sum()
        stol = tol if stage == n_stages else max(tol, STAGE_TOL)
        eps0 = 0.5 * min(float(pd.area.min()), float(target.min()))
        g = pd.area - target
        res = _rel_residual(pd.area, target)
        while res > stol and iterations < max_iterations:
            c_e = _hessian_weights(Pr, pd)
            d = None
            if REUSE_FACTOR and factorizations and not refactor:
                d, its = _pcg(solver, pd.edges, c_e, free, g, target)
                pcg_iterations += its
                # a slow convergence says the Hessian has drifted: factorise at the next step
                refactor = d is None or its > PCG_REFACTOR_AFTER
            if d is None:
                refactor = False
                d = np.zeros(len(Pr))
                # the matrix only here (a PCG step needs none), the pinned site's row and column left out
                d[free] = solver.solve(_free_hessian(pd.edges, c_e, free), -g[free])
                # iterative refinement: sites 1e-10 apart need the differences of d to ~1e-20
                # while d itself is ~1e-9 (a weakly coupled cluster moves as one)
                for _ in range(REFINEMENT_STEPS):
                    r = -g - _apply_hessian(pd.edges, c_e, d)
                    d[free] += solver.resolve(r[free])
                factorizations += 1
            d -= d.mean()
            gn = float(np.linalg.norm(g / target))
            step = _damped_step(Pr, hr, d, pd, target, eps0, gn, min_step, backend)
            if step is None:  # no damping accepted: the diagonally scaled gradient, same rule
                dg = -g / np.maximum(_hessian_diagonal(pd.edges, c_e, len(g)), 1e-300)
                dg -= dg.mean()
                step = _damped_step(Pr, hr, dg, pd, target, eps0, gn, min_step, backend)
                if step is None:
                    empty = int((power_diagram(Pr, hr + min_step * d, previous=pd, backend=backend).area <= 0).sum())
                    why = (f"{empty} sites lose their cells even for tiny steps ({pd.source} triangulation)"
                           if empty else "the Newton step could not be damped")
                    failure = f"optimal transport failed: {why} (max relative cell-area error {res:.3g} in stage {stage}/{n_stages})"
                    if not partial:
                        raise ParameterizationError(failure)
                    break
                gradient_steps += 1
            hn, pdn, gnew, tau, k = step
            halvings += k
            iterations += 1
            hr, pd, g = hn, pdn, gnew
            res = _rel_residual(pd.area, target)
            history.append({"stage": stage, "residual": res, "tau": tau})
            log(f"  OT stage {stage}/{n_stages} iteration {iterations}: max rel. error {res:.3g} (step {tau:g})", quiet=quiet, detail=True)
            short = short + 1 if tau <= 1 / 64 else 0
            if stall and short >= stall:
                failure = (f"optimal transport stalled: {short} steps in a row of at most 1/64 "
                           f"(max relative cell-area error {res:.3g} in stage {stage}/{n_stages})")
                if not partial:
                    raise ParameterizationError(failure)
                break
        stage_reached = stage
        if failure:
            break
        if stage == n_stages:
            converged = res <= tol
    h_full = hr[red]
    return OTResult(
        h=h_full - h_full.mean(),
        area=pd.area[red] * (nu / nu_r[red]),
        centroid=pd.centroid[red],
        nu=nu,
        residual=_rel_residual(pd.area, nu_r),
        converged=converged,
        iterations=iterations,
        halvings=halvings,
        seconds=time.perf_counter() - t_start,
        stages=n_stages,
        merged=int(n - len(keep)),
        history=history,
        backend=built,
        gradient_steps=gradient_steps,
        factorizations=factorizations,
        pcg_iterations=pcg_iterations,
        failure=failure,
        stage_reached=stage_reached,
    )


def _damped_step(P, h, d, pd, target, eps0, gn, min_step, backend):
    """The damping rule of Kitagawa, Mérigot & Thibert along ``d``: the largest ``τ = 2^-k``
    (down to ``min_step``) whose cells are all at least ``eps0`` and whose residual falls by
    ``1 - τ/2``; ``(h, diagram, gradient, τ, k)`` or None.  Each trial diagram starts from
    ``pd``'s (flips, or CGAL's insertion order when it is built anew)."""
    tau = 1.0
    k = 0
    while tau >= min_step:
        hn = h + tau * d
        pdn = power_diagram(P, hn, previous=pd, backend=backend)
        gnew = pdn.area - target
        if pdn.area.min() >= eps0 and np.linalg.norm(gnew / target) <= (1 - tau / 2) * gn:
            return hn, pdn, gnew, tau, k
        tau *= 0.5
        k += 1
    return None
