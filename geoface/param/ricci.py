"""Discrete Ricci flow / discrete conformal map of a disk onto a rectangle.

Energy
------
We minimise the convex discrete conformal energy of Springborn, Schröder & Pinkall
(CETM, "Conformal equivalence of triangle meshes", 2008) — the variational form of
discrete surface Ricci flow in the vertex-scaling setting of Jin, Kim, Luo & Gu (2008).
With log conformal factors ``u`` the new lengths are

    l~_ij = exp((u_i + u_j) / 2) * l_ij,                       (vertex scaling)

and, writing ``lam = 2 log l~`` and ``a_k`` for the angle opposite edge ``k``,

    f_T(lam) = 1/2 sum_k a_k lam_k + sum_k Л(a_k)               (Л: Lobachevsky)
    E(u)     = sum_T [ 2 f_T(lam~) - pi/2 sum_k lam~_k ] + sum_i Theta_i u_i

    dE/du_i   = Theta_i - sum_{T ∋ i} a_i^T                      (target - angle sum)
    d2E/du2   = L(u), the cotangent Laplacian of the current metric  (eq. 2 of the paper)

so ``grad E = 0`` exactly when every vertex reaches its target angle sum.  Targets:
``2 pi`` inside (curvature 0), ``pi`` on the boundary (geodesic curvature 0) and ``pi/2``
at the four corners, which satisfies Gauss–Bonnet for a disk.  ``E`` is convex on all of
R^n once triangles that violate the triangle inequality take angles (pi, 0, 0) (the C^1
extension of Bobenko, Pinkall & Springborn), so the flow never produces NaN.

Newton's method: solve ``L d = -grad`` with one vertex fixed (gauge: the energy is
invariant under adding a constant), then backtracking line search on ``E`` (Armijo).

Layout: the flat metric is unfolded triangle by triangle (breadth first); the boundary is
then a rectangle with the corners at its corners.

>>> from geoface.synth import spherical_cap
>>> V, F = spherical_cap(1.0, 1.0, 12)
>>> res = ricci_flow_rectangle(V, F)
>>> res.converged, res.residual < 1e-9
(True, True)
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidMeshError, ParameterizationError
from ..mesh.core import boundary_loops, check_mesh, edge_topology
from ..progress import log
from ..tol import tol
from .corners import default_corners
from .delaunay import IntrinsicTriangulation, flip_flat_degenerate
from .tracking import FlipTracker
from .intrinsic import corner_angles, cotan_laplacian, cotan_weights, edge_lengths, lobachevsky
from .linsolve import SPDSolver
from .layout import align_rectangle, layout, to_unit_square  # noqa: F401  (to_unit_square: public here too)
from .ricci_mesh import degenerate_boundary_edges, flip_ears, n_degenerate
from .ricci_result import RicciFlowResult


#: trial steps whose log conformal factors span more than this are refused: lengths e^±100 keep
#: the products of Heron's formula and Ptolemy's flips finite (real scans span up to ~20)
MAX_LOG_SCALE_RANGE = 200.0
#: a triangulation with an angle outside these (radians) starts on intrinsic Delaunay flips
POOR_MIN_ANGLE = np.radians(1.0)
POOR_MAX_ANGLE = np.radians(177.0)
#: on intrinsic flips, a step that makes more degenerate triangles than the iterate has is still
#: taken when backtracking has shrunk it below this (measured: a 30K-vertex scan-like disk 26
#: Newton steps with 1e-3, 16 with 0.25; a 189K one 11 with either, and no convergence with 1)
FLIP_GUARD_STEP = 0.25


def _energy_terms(lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-face ``2 f_T(lam) - pi/2 sum(lam)`` and angles, for ``lam = 2 log l`` (m, 3).  A line
    search's trial step may overflow the lengths: the energy is then not finite, and the step refused."""
    with np.errstate(over="ignore", invalid="ignore"):
        ang = corner_angles(np.exp(0.5 * lam))
    f2 = (ang * lam).sum(1) + 2.0 * lobachevsky(ang).sum(1)
    return f2 - 0.5 * np.pi * lam.sum(1), ang


class RicciFlowSolver:
    """Discrete conformal (Ricci flow) map of a topological disk onto a rectangle.

    Keeps the mesh, targets and the linear solver's symbolic analysis between calls,
    so several corner sets (augmentation) reuse the set-up and warm start from each other.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64 — a topological disk (see ``geoface.repair.make_disk``)
    tolerance : float — stop when max |target - angle sum| <= tolerance (default 1e-9 rad)
    max_iterations : int — Newton iterations (default 100)
    linear_solver : "auto" | "cholmod" | "splu" — see :class:`geoface.param.linsolve.SPDSolver`
    flips : "auto" | "never" | "always" — intrinsic Delaunay (Ptolemy) flips: from the start on
        a mesh with needles or caps (an angle under 1° or over 177°), else only when the fixed
        triangulation fails (default); never; or always
    max_refinements : int — with flips, rounds of boundary refinement (default 8, 0: none).
        Boundary edges are never flipped, so the flow can push an interior vertex onto a
        boundary edge (a triangle with an angle of pi there, or past the triangle
        inequality).  Such edges are split at their 3D midpoints and the flow re-run; the
        result's ``V`` then has the new vertices appended (``split_edges`` lists them).
    """

    def __init__(self, V, F, *, tolerance: float = 1e-9, max_iterations: int = 100, linear_solver: str = "auto", flips: str = "auto",
                 max_refinements: int = 8):
        if flips not in ("auto", "never", "always"):
            raise InvalidMeshError(f"flips must be 'auto', 'never' or 'always'; got {flips!r}")
        self.flips = flips
        V, F = check_mesh(V, F)
        loops = boundary_loops(F)
        if len(loops) != 1:
            raise ParameterizationError(f"Ricci flow to a rectangle needs a topological disk (one boundary loop); got {len(loops)} loops")
        used = np.zeros(len(V), bool)
        used[F.ravel()] = True
        if not used.all():
            raise ParameterizationError(f"{int((~used).sum())} vertices are not used by any face; run make_disk first")
        et = edge_topology(F)
        if (et.edge_faces > 2).any():
            raise ParameterizationError("mesh is not manifold; run make_disk first")
        F, self.ears_flipped = flip_ears(V, F, loops[0])
        self.n_input = len(V)
        self.split_edges = np.zeros((0, 2), np.int64)
        self._set_mesh(V, F)
        if (self.l0 <= 0).any():
            raise ParameterizationError("mesh has zero-length edges; run make_disk first")
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.max_refinements = int(max_refinements)
        # COLAMD: the cheapest analysis + factorization of a 50K-vertex cotangent Laplacian
        # here (0.18 s + 0.13 s per refactorization, against METIS 0.43 s + 0.14 s)
        self.solver = SPDSolver(linear_solver, ordering="colamd")
        self._u_warm: np.ndarray | None = None
        self._tri_warm: IntrinsicTriangulation | None = None

    def _set_mesh(self, V: np.ndarray, F: np.ndarray) -> None:
        self.V, self.F = V, F
        self.n = len(V)
        self.boundary = boundary_loops(F)[0]
        self.is_boundary = np.zeros(self.n, bool)
        self.is_boundary[self.boundary] = True
        self.l0 = edge_lengths(V, F)
        self.lam0 = 2.0 * np.log(self.l0)
        with np.errstate(invalid="ignore", divide="ignore"):
            ang = corner_angles(self.l0)
        #: needles or caps: an angle under 1 degree or over 177 (see ``solve``)
        self.poor_triangulation = bool(len(ang) and (ang.min() < POOR_MIN_ANGLE or ang.max() > POOR_MAX_ANGLE))

    def _start_triangulation(self) -> IntrinsicTriangulation:
        """The intrinsic triangulation a flow starts on: the last solve's when it was of this
        mesh (the corner sets of one mesh differ only at their four corners), else the mesh's."""
        warm = self._tri_warm
        if warm is not None and warm.F0.shape == self.F.shape and np.array_equal(warm.F0, self.F):
            self._tri_warm = None
            return warm
        return IntrinsicTriangulation(self.F, self.l0)

    def refine_boundary(self, min_vertices: int, *, rounds: int = 4) -> int:
        """Refine the triangles along the boundary (red-green,
        :func:`geoface.param.ricci_mesh.refine_boundary_band`: the boundary doubles its vertices
        each round, the triangles keep their shapes) until it has at least ``min_vertices``
        vertices, at most ``rounds`` rounds. Corners can then sit within about ``1 /
        min_vertices`` of the boundary where they are asked for, on a coarse scan too (a neck
        cut of 18 edges puts a corner up to half an edge, a 36th of the boundary, from its
        place: the face turns by that in the image). New vertices are edge midpoints appended as
        the flow's own splits (``split_edges``). Returns how many were added."""
        from .ricci_mesh import refine_boundary_band

        n0 = self.n
        for _ in range(int(rounds)):
            if len(self.boundary) >= min_vertices:
                break
            V, F, edges = refine_boundary_band(self.V, self.F)
            self.split_edges = np.vstack([self.split_edges, edges])
            self._set_mesh(V, F)
        if self.n > n0:
            self._u_warm = None
        return self.n - n0

    def _split_boundary_edges(self, edges: list[tuple[int, int]]) -> None:
        """Split boundary edges ``a -> b`` of the mesh at their 3D midpoints (the triangle
        on each is split in two); new vertices are appended, so indices stay valid."""
        V, F = self.V, self.F.copy()
        newV, newF, done = [], [], []
        for a, b in edges:
            # the face holding the boundary half-edge a -> b
            hit = np.flatnonzero(((F == a) & (np.roll(F, -1, axis=1) == b)).any(1))
            if len(hit) != 1:
                continue
            f = int(hit[0])
            k = int(np.flatnonzero(F[f] == a)[0])
            x = int(F[f, (k + 2) % 3])
            m = len(V) + len(newV)
            newV.append(0.5 * (V[a] + V[b]))
            F[f] = (a, m, x)
            newF.append((m, b, x))
            done.append((a, b))
        if not done:
            return
        self.split_edges = np.vstack([self.split_edges, np.array(done, np.int64)])
        self._set_mesh(np.vstack([V, np.array(newV)]), np.vstack([F, np.array(newF, np.int64)]))

    # ------------------------------------------------------------------ energy
    def targets(self, corners: np.ndarray) -> np.ndarray:
        """Target angle sums: 2 pi inside, pi on the boundary, pi/2 at the corners."""
        th = np.where(self.is_boundary, np.pi, 2 * np.pi)
        th[corners] = np.pi / 2
        return th

    def _lam(self, u: np.ndarray, F: np.ndarray | None = None, tri: "IntrinsicTriangulation | None" = None) -> np.ndarray:
        """``2 log`` of the scaled lengths, per face corner (opposite edge)."""
        if tri is not None:
            return 2.0 * np.log(tri.corner_lengths(u))
        F = self.F if F is None else F
        # edge opposite corner k joins F[:, k+1] and F[:, k+2]
        return self.lam0 + u[F[:, [1, 2, 0]]] + u[F[:, [2, 0, 1]]]

    def energy(self, u: np.ndarray, theta: np.ndarray, F: np.ndarray | None = None, tri=None) -> tuple[float, np.ndarray, np.ndarray]:
        """``E(u)``, its gradient ``target - angle sum`` and the corner angles."""
        F = self.F if F is None else F
        e, ang = _energy_terms(self._lam(u, F, tri))
        sums = np.bincount(F.ravel(), weights=ang.ravel(), minlength=self.n)
        return float(e.sum() + theta @ u), theta - sums, ang

    def hessian(self, u: np.ndarray) -> sp.csr_matrix:
        return cotan_laplacian(np.exp(0.5 * self._lam(u)), self.F, self.n)

    # ------------------------------------------------------------------ solve
    def solve(self, corners=None, u0: np.ndarray | None = None, *, quiet: bool | None = None) -> RicciFlowResult:
        """Run Newton's method and lay the result out as a rectangle.

        ``corners``: four boundary vertices in boundary order (default:
        :func:`geoface.param.corners.default_corners`).  ``u0``: warm start (default: the
        previous solution of this solver, else zeros).

        With ``flips="auto"`` (the default) the flow first keeps the mesh's triangulation;
        if that does not converge to a non-degenerate metric (pleated or needle-shaped
        regions can make that impossible), it is re-run on an intrinsic Delaunay
        triangulation maintained by Ptolemy flips, which always has a solution; the
        result's ``F`` is then that triangulation (``intrinsic_flips`` > 0).
        """
        t0 = time.perf_counter()
        corners = self._check_corners(default_corners(self.V, self.F) if corners is None else corners)
        theta = self.targets(corners)
        if abs(theta.sum() - np.pi * len(self.F)) > 1e-6:
            raise ParameterizationError("targets violate Gauss-Bonnet (is the mesh a disk?)")
        u = np.zeros(self.n) if u0 is None and self._u_warm is None else np.array(self._u_warm if u0 is None else u0, np.float64)
        if u.shape != (self.n,):
            u = np.concatenate([u, np.zeros(self.n - len(u))]) if len(u) < self.n else u[: self.n]
        tri = None
        # "auto": a mesh with needles or caps (an angle under 1 degree or over 177) starts on its
        # intrinsic Delaunay triangulation, decided from the mesh (fins, slivers and hole patches
        # of real scans); otherwise the fixed triangulation is tried first, and given up for
        # flips when it has not converged after 30 Newton iterations (they converge in ~5 when a
        # solution exists) or its line search has stalled (3 iterations in a row with steps
        # <= 1/16: degenerate triangles block every full step)
        auto = self.flips == "auto"
        if self.flips == "always" or (auto and self.poor_triangulation):
            tri = self._start_triangulation()
        cap = min(self.max_iterations, 30) if auto and tri is None else self.max_iterations
        u, ang, F, it, res, history, converged = self._newton(corners, theta, u, tri, quiet, cap,
                                                              stall=3 if auto and tri is None else 0)
        if auto and tri is None and (not converged or n_degenerate(ang) > 0):
            log(f"ricci: no flat metric on the mesh's own triangulation (residual {res:.2e} after {it} iterations); "
                "continuing on its intrinsic Delaunay triangulation", quiet=quiet, detail=True)
            tri = self._start_triangulation()
            u, ang, F, it2, res, h2, converged = self._newton(corners, theta, np.zeros(self.n), tri, quiet, self.max_iterations)
            it += it2
            history += h2
        rounds = 0
        while tri is not None and converged:
            if n_degenerate(ang) > 0:
                flip_flat_degenerate(tri, u)
                F = tri.F
                _, _, ang = self.energy(u, theta, F, tri)
            bad = degenerate_boundary_edges(tri, u)
            if not bad or rounds >= self.max_refinements:
                break
            rounds += 1
            log(f"ricci: {len(bad)} boundary triangles flattened by the flow; splitting their boundary edges (round {rounds})", quiet=quiet, detail=True)
            n_old = self.n
            self._split_boundary_edges(bad)
            if self.n == n_old:
                break
            theta = self.targets(corners)
            u = np.concatenate([u, 0.5 * (u[self.split_edges[-(self.n - n_old) :, 0]] + u[self.split_edges[-(self.n - n_old) :, 1]])])
            tri = IntrinsicTriangulation(self.F, self.l0)
            u, ang, F, it2, res, h2, converged = self._newton(corners, theta, u, tri, quiet, self.max_iterations)
            it += it2
            history += h2
        self._u_warm = u.copy()
        # the next corner set starts from this triangulation: Delaunay already for a metric
        # near its own, so its flow flips little (a copy: this result's flip tracker keeps its log)
        self._tri_warm = None if tri is None else tri.copy()
        lengths = np.exp(0.5 * self._lam(u, F, tri))
        degenerate = n_degenerate(ang)
        uv = layout(lengths, F, ang, None if tri is None else tri.twin)
        uv, w, h = align_rectangle(uv, corners)
        if tol.strict and converged:
            k = np.where(self.is_boundary, np.pi, 2 * np.pi) - np.bincount(F.ravel(), weights=ang.ravel(), minlength=self.n)
            if abs(k.sum() - 2 * np.pi) > 1e-8:
                raise ParameterizationError("strict: Gauss-Bonnet violated after the flow")
        return RicciFlowResult(
            uv=uv, u=u, corners=corners, width=w, height=h, converged=bool(converged), iterations=it, residual=res,
            seconds=time.perf_counter() - t0, history=history, degenerate_triangles=degenerate,
            F=F.copy(), ears_flipped=self.ears_flipped, intrinsic_flips=0 if tri is None else tri.flips,
            V=self.V, split_edges=self.split_edges.copy(),
            mesh_F=self.F.copy(), tracker=None if tri is None or tri.flips == 0 else FlipTracker.from_triangulation(tri),
        )

    def _newton(self, corners, theta, u, tri, quiet, max_iterations, stall: int = 0):
        """Damped Newton on E; with ``tri`` the triangulation is kept Delaunay (Ptolemy flips).

        ``stall`` > 0: stop (unconverged) after that many iterations in a row whose step was
        at most 1/16 — a damped Newton that converges takes full steps within a few iterations."""
        short = 0
        gauge = int(corners[0])
        u = u - u[gauge]
        free = np.ones(self.n, bool)
        free[gauge] = False

        def evaluate(uu):
            # a trial step so long that the scaled lengths overflow is refused (and before any
            # flip: a Delaunay test on infinite lengths would flip without end)
            refused = not (np.isfinite(uu).all() and np.ptp(uu) < MAX_LOG_SCALE_RANGE)
            if tri is not None and not refused:
                try:
                    tri.make_delaunay(uu)
                except ParameterizationError:
                    refused = True
            F = self.F if tri is None else tri.F
            if refused:
                return np.inf, np.full(self.n, np.nan), np.full(F.shape, np.nan), F
            E, g, ang = self.energy(uu, theta, F, tri)
            return E, g, ang, F

        E, g, ang, F = evaluate(u)
        res = float(np.abs(g).max())
        history = [res]
        it = 0
        converged = res <= self.tolerance
        while not converged and it < max_iterations:
            it += 1
            if tri is None:  # fixed pattern: assemble straight into the reduced CSC matrix
                H = self._reduced_hessian(np.exp(0.5 * self._lam(u, F, tri)), F, free)
            else:
                H = cotan_laplacian(np.exp(0.5 * self._lam(u, F, tri)), F, self.n)[free][:, free]
            d = np.zeros(self.n)
            d[free] = self._newton_direction(H, -g[free])  # Newton: H d = -grad E, grad E = g
            slope = g @ d  # directional derivative of E along d (negative for descent)
            if not np.isfinite(slope) or slope >= 0:
                d = np.where(free, -g, 0.0)  # fall back to gradient descent
                slope = g @ d
            # backtracking: Armijo on E, and while the step creates degenerate triangles
            # that the current metric does not have (the energy's extension would accept
            # them, but the minimiser of a realisable problem has none); with intrinsic flips the
            # guard gives way sooner (below FLIP_GUARD_STEP: flips and the boundary refinement after the
            # solve resolve what is left, and a slivered mesh would otherwise crawl)
            n_deg = n_degenerate(ang)
            t = 1.0
            while True:
                un = u + t * d
                En, gn, angn, Fn = evaluate(un)
                armijo = np.isfinite(En) and En <= E + 1e-4 * t * slope
                # near the solution the decrease (~ residual^2) is below the rounding of E:
                # then a step that reduces the residual is accepted instead
                noise = abs(t * slope) < 1e-11 * max(abs(E), 1.0)
                if noise and np.isfinite(En):
                    armijo = float(np.abs(gn).max()) < float(np.abs(g).max())
                if armijo and (n_degenerate(angn) <= n_deg or t < (FLIP_GUARD_STEP if tri is not None else 1e-6)):
                    break
                t *= 0.5
                if t < 1e-12:
                    break
            if not np.isfinite(En):  # no step at all: keep the iterate (and its triangulation)
                E, g, ang, F = evaluate(u)
                break
            u, E, g, ang, F = un, En, gn, angn, Fn
            res = float(np.abs(g).max())
            history.append(res)
            log(f"ricci: iteration {it}: max |K - target| = {res:.3e}, step {t:g}", quiet=quiet, detail=True)
            converged = res <= self.tolerance
            if t < 1e-12:
                break
            short = short + 1 if t <= 1 / 16 else 0
            if stall and short >= stall and not converged:
                break
        return u, ang, F, it, res, history, converged

    def _reduced_hessian(self, l: np.ndarray, F: np.ndarray, free: np.ndarray) -> sp.csc_matrix:
        """The cotangent Laplacian restricted to the ``free`` vertices, as CSC with sorted
        indices, assembled by one ``bincount`` into a sparsity pattern computed once per
        (triangulation, gauge) — the same matrix as ``cotan_laplacian(l, F, n)[free][:, free]``."""
        key = (F.shape, int(np.flatnonzero(~free)[0]) if (~free).any() else -1)
        cache = getattr(self, "_hess_cache", None)
        if cache is None or cache[0] != key or cache[1] is not F:
            i = F[:, [1, 2, 0]].ravel()
            j = F[:, [2, 0, 1]].ravel()
            rows = np.concatenate([i, j, i, j])
            cols = np.concatenate([j, i, i, j])
            idx = np.cumsum(free) - 1
            valid = free[rows] & free[cols]
            nf = int(free.sum())
            keys = idx[cols[valid]].astype(np.int64) * nf + idx[rows[valid]]
            uk, pos = np.unique(keys, return_inverse=True)
            indptr = np.searchsorted(uk // nf, np.arange(nf + 1)).astype(np.int32)
            indices = (uk % nf).astype(np.int32)
            cache = (key, F, valid, pos, indptr, indices, nf)
            self._hess_cache = cache
        _, _, valid, pos, indptr, indices, nf = cache
        w = 0.5 * cotan_weights(l).ravel()
        vals = np.concatenate([-w, -w, w, w])[valid]
        data = np.bincount(pos, vals, minlength=len(indices))
        return sp.csc_matrix((data, indices, indptr), shape=(nf, nf))

    def _newton_direction(self, H: sp.csr_matrix, rhs: np.ndarray) -> np.ndarray:
        """Solve ``H d = rhs``; a Hessian made singular by degenerate triangles (vertices
        whose cotangent weights all vanish) is regularised by a tiny multiple of I."""
        try:
            d = self.solver.solve(H, rhs)
            if np.isfinite(d).all():
                return d
        except Exception:  # SuperLU: singular; CHOLMOD: not positive definite
            pass
        eps = 1e-10 * max(float(np.abs(H.diagonal()).max()), 1.0)
        return SPDSolver("splu").solve(H + eps * sp.identity(H.shape[0], format="csr"), rhs)

    def _check_corners(self, corners) -> np.ndarray:
        try:
            raw = np.asarray(corners)
        except (TypeError, ValueError):
            raise ParameterizationError(f"corners must be 4 distinct vertex indices; got {corners!r}") from None
        if raw.dtype.kind not in "iu" and not (raw.dtype.kind == "f" and np.isfinite(raw).all() and (raw == np.round(raw)).all()):
            raise ParameterizationError(f"corners must be 4 integer vertex indices; got {corners!r}")
        c = raw.astype(np.int64).ravel()
        if c.shape != (4,) or len(np.unique(c)) != 4:
            raise ParameterizationError(f"corners must be 4 distinct vertex indices; got {corners!r}")
        pos = {int(v): i for i, v in enumerate(self.boundary)}
        if any(int(x) not in pos for x in c):
            raise ParameterizationError(f"corners must lie on the boundary; {[int(x) for x in c if int(x) not in pos]} do not")
        p = np.array([pos[int(x)] for x in c])
        # must appear in boundary order (cyclically increasing)
        if ((np.diff(np.r_[p, p[0]]) % len(self.boundary)) == 0).any() or ((p - p[0]) % len(self.boundary)).tolist() != sorted(((p - p[0]) % len(self.boundary)).tolist()):
            raise ParameterizationError("corners must be given in boundary order (counter-clockwise)")
        return c


def ricci_flow_rectangle(V, F, corners=None, **kw) -> RicciFlowResult:
    """One-shot: build a :class:`RicciFlowSolver`, solve once, return the result."""
    return RicciFlowSolver(V, F, **kw).solve(corners)
