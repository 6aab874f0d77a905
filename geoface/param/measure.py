"""Measure-preserving map of a disk onto the unit square (the head paper, after Zhao et al.).

Start from a map ``uv`` of the disk onto the unit square with the boundary on the square's
sides (the Ricci-flow rectangle, stretched).  Each vertex carries the mass
``ν_i = λ_i · ⅓ · (areas of its faces)``, with ``λ_i = lam`` on the region of interest and 1
elsewhere; semi-discrete OT gives each vertex a power cell of area ``ν_i`` and its new UV is
the cell's centroid.  So a region of interest of area share ``a`` gets ``λa / (1 + (λ-1)a)``
of the square at β = 0 (the face is magnified; ``blend`` below).

``blend`` (β) mixes in the starting map's own area: ``ν_i ∝ (λ_i · area_i)^(1-β) ·
(uv area_i)^β``.  β = 0 is the paper's measure.  An area-preserving map squeezes the band
next to the cut (a head's neck, mapped onto the whole square's perimeter) into a few rows of
long thin pixels, and the reconstruction cuts the corners of the jaw there; a conformal start
keeps that band wide.  A small β trades some of the face's share for smaller errors along the
cut; it also gives less to what the conformal map shrinks (a body's limbs): measured in
docs/benchmarks.md, "The target measure".

``feature`` (γ) gives sharp spots more pixels: a vertex's mass is multiplied by ``1 + γ·f``,
``f = min(1, |angle defect| / 60°)`` taken as the largest over the vertex and its neighbours
(on the disk's own boundary, the defect from a straight line).  A geometry image cuts the tip
off a cone or a crease's end by an amount proportional to the pixel spacing there (not its
square, as on a smooth surface): a slit-shaped hole closed by the repair (a head's mouth, its
corners), a fingertip, the rim of a filled eye.  ``γ = 0`` is the paper's measure; ``convert``
uses 4 (docs/benchmarks.md, "Sharp spots").

Two details make the result usable as a parameterization:

* Boundary vertices stay on their side of the square (a centroid lies inside its cell, a
  little off the side, and is moved onto it); corners stay at the corners.
* Centroid maps fold triangles where the mesh's connectivity disagrees with the power
  diagram (where the density changes fast, and around long protrusions of real scans).
  The final map is fold-free by construction: a convex-combination map whose weights are
  the centroid map's own mean value coordinates wherever it does not fold (so it *is* the
  centroid map there) and the conformal map's around folds
  (:func:`geoface.param.foldfree.convex_combination_map`; Tutte/Floater: it cannot fold).
  How far it moved from the centroids is reported: the per-vertex area error against the
  target masses before and after, and the largest displacement.

It cannot fail on a valid disk.  Where the conformal factor spans so many orders of magnitude
that neighbouring sites crowd below what double precision separates (long protrusions, fins,
slivers), Newton's method on the conformal sites stalls; it is then given up fast (a few
steps of at most 1/64) and the sites are moved first: an area-balanced embedding
(:func:`geoface.param.balance.area_balanced_map`, fold-free convex-combination maps
reweighted until every vertex's share of the square is within a factor of about e^2.5 of its
mass) places them, and OT from there converges.  Should that solve not reach ``tol`` either,
the better of its fold-free map and the balanced embedding is returned, with the tolerance
reached.  A solve from the balanced sites that stops short (a cell below what double
precision resolves, near the end) is started again from the centroids it reached, made
fold-free: they are sites whose cells are closer to their masses (up to four times).
``MeasureMapResult.path`` says which way each map was made.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterizationError
from ..mesh.core import boundary_loops, check_mesh, signed_uv_areas, uv_vertex_areas, vertex_areas
from .balance import BalancedMap, area_balanced_map, log_area_ratio
from .foldfree import FoldFreeResult, convex_combination_map, square_sides
from .tutte import fold_free_start
from ..progress import log
from .ot import OTResult, semi_discrete_ot

#: the first OT attempt, from the conformal sites, gives up after this many short steps in a row
DIRECT_STALL = 4
#: solves started again from the centroids the last one reached, when it stopped short
MAX_RESTARTS = 4
#: the angle defect at which a vertex counts fully as a sharp spot (``feature`` masses)
FEATURE_ANGLE = np.radians(60.0)

__all__ = ["MeasureMapResult", "MeasurePreservingSolver", "measure_preserving_map", "sharpness", "signed_uv_areas", "area_error"]


def sharpness(V, F, boundary=None) -> np.ndarray:
    """Per vertex in [0, 1]: ``min(1, |angle defect| / FEATURE_ANGLE)``, then the largest over
    each vertex and its neighbours.  The defect is ``2π - Σ angles`` inside and ``π - Σ angles``
    at ``boundary`` vertices (default: the mesh's boundary loops), so a flat disk and its
    straight rim are 0; a cone tip, a crease's end or a corner of a slit-shaped hole approach 1."""
    V, F = check_mesh(V, F)
    n = len(V)
    angle = np.empty(F.shape)
    for k in range(3):  # the angle at corner k, between the edges to the next two corners
        a = V[F[:, (k + 1) % 3]] - V[F[:, k]]
        b = V[F[:, (k + 2) % 3]] - V[F[:, k]]
        angle[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), (a * b).sum(1))
    total = np.bincount(F.ravel(), angle.ravel(), minlength=n)
    if boundary is None:
        loops = boundary_loops(F)
        boundary = np.concatenate(loops) if loops else np.zeros(0, np.int64)
    defect = 2.0 * np.pi - total
    defect[boundary] = np.pi - total[boundary]
    f = np.minimum(1.0, np.abs(defect) / FEATURE_ANGLE)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    g = f.copy()
    np.maximum.at(g, edges[:, 0], f[edges[:, 1]])
    np.maximum.at(g, edges[:, 1], f[edges[:, 0]])
    return g


@dataclass(frozen=True)
class MeasureMapResult:
    """Result of :func:`measure_preserving_map`.

    uv : (n, 2) the map (fold-free unless ``fold_free=False``); ot : the OT solve that made it
    (None on the ``"balanced"`` path); flipped_before : folded triangles of the centroid map;
    flipped_after : of ``uv`` (0); fold_free : the convex-combination step's report (None when
    the step was skipped); area_error_before / area_error_after : mean |log(a_i / ν_i)| of the
    per-vertex areas (⅓ of adjacent UV triangles) against the target masses, for the centroid
    map and ``uv``; roi_share : share of the square covered by the region of interest's
    triangles; sites : where OT's sites were (``"conformal"``: the starting map, or
    ``"balanced"``: an area-balanced embedding of it); balanced : that embedding's report;
    attempts : every OT solve tried (sites, converged, residual, iterations, error);
    residual : the tolerance reached, max |w_i - ν_i| / ν_i of the OT cells (of the vertex
    areas on the ``"balanced"`` path); converged : ``residual <= tol``; restarts : how many times
    the solve from the balanced sites was started again from the centroids it had reached.
    """

    uv: np.ndarray
    ot: OTResult | None
    flipped_before: int
    flipped_after: int
    seconds: float
    fold_free: FoldFreeResult | None = None
    area_error_before: float = 0.0
    area_error_after: float = 0.0
    roi_share: float | None = None
    sites: str = "conformal"
    balanced: BalancedMap | None = None
    attempts: list = field(default_factory=list)
    residual: float = 0.0
    converged: bool = True
    restarts: int = 0

    @property
    def path(self) -> str:
        """How the map was made, for reports: ``"ot"`` (OT from the conformal sites, the
        centroids as they are), ``"ot+convex-combination"`` (their folds replaced by the
        fold-free step), ``"balanced+ot"`` / ``"balanced+ot+convex-combination"`` (the same from
        the sites of an area-balanced embedding) or ``"balanced"`` (the embedding itself: OT did
        not reach a better map)."""
        if self.ot is None:
            return "balanced"
        base = "ot" if self.sites == "conformal" else "balanced+ot"
        if self.fold_free is None or self.flipped_before == 0:
            return base
        return base + "+convex-combination"


def _snap(uv_new: np.ndarray, bnd: np.ndarray, sides: np.ndarray) -> np.ndarray:
    out = uv_new.copy()
    p = out[bnd]
    p[sides[:, 0], 0] = 0.0
    p[sides[:, 1], 0] = 1.0
    p[sides[:, 2], 1] = 0.0
    p[sides[:, 3], 1] = 1.0
    out[bnd] = p
    return out


def area_error(F: np.ndarray, uv: np.ndarray, nu: np.ndarray) -> float:
    """Mean |log(a_i / ν_i)| of per-vertex UV areas (⅓ of adjacent triangles, normalised)
    against target masses ``nu`` (normalised)."""
    va = uv_vertex_areas(F, uv)
    va = va / va.sum()
    nu = nu / nu.sum()
    return float(np.mean(np.abs(np.log(np.maximum(va, 1e-300) / nu))))


#: the largest ROI mass factor: beyond it the cells' masses span more than the linear solves hold
MAX_LAM = 1e6


class MeasurePreservingSolver:
    """Measure-preserving maps of one disk ``(V, F)``: the mesh is checked and its vertex areas
    and boundary found once; :meth:`solve` maps any starting ``uv`` (several corner sets, several
    ``lam``). A solve from the same ``uv`` as the last one starts OT from the heights that solve
    reached (a warm start: a sweep of ``lam`` or ``roi`` on one map).

    >>> from geoface.synth import square_grid
    >>> V, F = square_grid(6)
    >>> uv = V[:, :2] - V[:, :2].min(0); uv /= uv.max(0)
    >>> solver = MeasurePreservingSolver(V, F)
    >>> solver.solve(uv).converged and solver.solve(uv, lam=2.0, roi=V[:, 0] < 0.5).converged
    True
    """

    def __init__(self, V, F, *, tol: float = 1e-3, fold_free: bool = True, linear_solver: str = "auto",
                 backend: str = "auto", quiet: bool | None = None):
        from .linsolve import METHODS
        from .power import BACKENDS

        if not (isinstance(tol, (int, float)) and np.isfinite(tol) and 0 < tol < 1):
            raise ParameterizationError(f"tol must be a number in (0, 1); got {tol!r}")
        if backend not in BACKENDS:
            raise ParameterizationError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
        if linear_solver not in METHODS:
            raise ParameterizationError(f"linear_solver must be one of {', '.join(METHODS)}; got {linear_solver!r}")
        V, F = check_mesh(V, F)
        if not boundary_loops(F):
            raise ParameterizationError("the mesh has no boundary (a closed surface): a measure-preserving map needs "
                                        "a disk (geoface.repair.make_disk)")
        n = len(V)
        va = vertex_areas(V, F)
        used = np.zeros(n, bool)
        used[F.ravel()] = True
        if not used.all():
            raise ParameterizationError(f"{int((~used).sum())} vertices are not used by any face")
        if (va <= 0).any() or not np.isfinite(va).all():
            # a vertex only in flat triangles still needs a cell: a tiny mass, not a failure
            floor = 1e-6 * float(np.median(va[va > 0])) if (va > 0).any() else 1.0
            log(f"  measure-preserving map: {int((va <= 0).sum())} vertices lie only in flat triangles; "
                f"they get a mass of {floor:.3g}", quiet=quiet, detail=True)
            va = np.where(np.isfinite(va) & (va > 0), va, floor)
        loops = boundary_loops(F)
        self.V, self.F, self.vertex_areas = V, F, va
        self.boundary = np.concatenate(loops) if loops else np.zeros(0, np.int64)
        self.tol, self.fold_free, self.linear_solver, self.backend, self.quiet = tol, fold_free, linear_solver, backend, quiet
        self._warm: tuple | None = None  # (uv, heights) of the last solve from the starting map
        self._sharpness: np.ndarray | None = None
        self.warm_started = False  # whether the last solve started from the previous heights

    def masses(self, roi=None, lam: float = 2.5, *, uv=None, blend: float = 0.0, feature: float = 0.0) -> np.ndarray:
        """The target masses ``ν_i = λ_i · (vertex area)``: ``lam`` on ``roi``, 1 elsewhere; with
        ``blend`` β > 0, ``ν_i^(1-β) · (uv area_i)^β`` (same total), ``uv`` the starting map;
        then times ``1 + γ f_i``, ``f`` the :func:`sharpness` and γ = ``feature``."""
        n = len(self.V)
        if not (np.isfinite(lam) and 0 < lam <= MAX_LAM):
            raise ParameterizationError(f"lam must be in (0, {MAX_LAM:g}]; got {lam}")
        if not (np.isfinite(blend) and 0.0 <= blend < 1.0):
            raise ParameterizationError(f"blend must be in [0, 1); got {blend}")
        if not (np.isfinite(feature) and feature >= 0):
            raise ParameterizationError(f"feature must be finite and >= 0; got {feature}")
        weight = np.ones(n)
        if roi is not None:
            roi = np.asarray(roi)
            if roi.shape != (n,):
                raise ParameterizationError(f"roi must be a ({n},) vertex mask; got shape {roi.shape}")
            if roi.dtype.kind not in "biu" and not (roi.dtype.kind == "f" and np.isin(roi, (0.0, 1.0)).all()):
                raise ParameterizationError("roi must be a boolean vertex mask (or 0/1 values)")
            weight = np.where(roi.astype(bool), float(lam), 1.0)
        va = self.vertex_areas
        # a vertex whose triangles are all flat (the flow's intrinsic flips can leave a corner on
        # a straight stretch of the boundary one triangle spanning it, of zero area on the
        # surface): the smallest area of the others, not zero, which no cell can match
        flat = va <= 1e-12 * va.max()
        if flat.any() and not flat.all():
            va = np.where(flat, va[~flat].min(), va)
        nu = weight * va
        if feature > 0:
            if self._sharpness is None:
                self._sharpness = sharpness(self.V, self.F, self.boundary)
            boost = 1.0 + feature * self._sharpness
        else:
            boost = 1.0
        if blend == 0.0:
            return nu * boost
        if uv is None:
            raise ParameterizationError("blend > 0 needs the starting map uv")
        ua = uv_vertex_areas(self.F, uv)
        pos = ua > 0
        # a vertex whose starting cells all collapsed: the smallest positive area, not zero
        ua = np.where(pos, ua, ua[pos].min() if pos.any() else 1.0)
        mixed = np.exp((1.0 - blend) * np.log(nu / nu.sum()) + blend * np.log(ua / ua.sum()))
        return mixed * (nu.sum() / mixed.sum()) * boost

    def solve(self, uv, *, roi=None, lam: float = 2.5, blend: float = 0.0, feature: float = 0.0, h0=None) -> "MeasureMapResult":
        """The measure-preserving map from ``uv`` (see :func:`measure_preserving_map`)."""
        V, F, quiet, tol = self.V, self.F, self.quiet, self.tol
        fold_free, linear_solver, backend = self.fold_free, self.linear_solver, self.backend
        t0 = time.perf_counter()
        uv = np.asarray(uv, np.float64)
        n = len(V)
        if uv.shape != (n, 2) or not np.isfinite(uv).all():
            raise ParameterizationError(f"uv must be a finite ({n}, 2) array")
        if uv.min() < -1e-9 or uv.max() > 1 + 1e-9:
            raise ParameterizationError("uv must lie in the unit square (use RicciFlowResult.unit_square())")
        nu = self.masses(roi, lam, uv=uv, blend=blend, feature=feature)
        roi = None if roi is None else np.asarray(roi)
        if h0 is not None:
            h0 = np.asarray(h0, np.float64)
            if h0.shape != (n,) or not np.isfinite(h0).all():
                raise ParameterizationError(f"h0 must be a finite ({n},) array of heights; got shape {h0.shape}")
        self.warm_started = False
        if h0 is None and self._warm is not None and np.array_equal(self._warm[0], uv):
            h0, self.warm_started = self._warm[1], True
        bnd = self.boundary
        sides = square_sides(uv[bnd])
        if len(bnd) and not sides.any(1).all():
            raise ParameterizationError("the starting map does not put every boundary vertex on the square's sides")
        orient = 1.0 if signed_uv_areas(F, uv).sum() >= 0 else -1.0
        attempts: list = []

        def attempt(sites_uv, label, **kw):
            t = time.perf_counter()
            try:
                r = semi_discrete_ot(sites_uv, nu, tol=tol, h0=h0 if label == "conformal" else None, linear_solver=linear_solver,
                                     backend=backend, partial=True, quiet=quiet, **kw)
            except ParameterizationError as e:  # no start at all (cells empty even after merging sites)
                attempts.append({"sites": label, "converged": False, "error": str(e), "seconds": time.perf_counter() - t})
                return None
            attempts.append({"sites": label, "converged": bool(r.converged), "residual": float(r.residual),
                             "iterations": int(r.iterations), "halvings": int(r.halvings), "stages": int(r.stages),
                             "gradient_steps": int(r.gradient_steps), "error": r.failure or None,
                             "seconds": time.perf_counter() - t})
            return r

        ot = attempt(uv, "conformal", stall=DIRECT_STALL)
        best = (ot, uv, "conformal") if ot is not None else None
        bal = None
        restarts = 0
        if ot is None or not ot.converged:
            # crowded sites: move them to an area-balanced embedding first (the normal path for
            # conformal factors spanning many orders of magnitude, not an error)
            bal = area_balanced_map(F, fold_free_start(F, uv), nu)
            log(f"  measure-preserving map: OT sites from an area-balanced embedding (worst log area ratio "
                f"{bal.start_max_log_ratio:.1f} -> {bal.max_log_ratio:.1f} in {bal.best_round} rounds)", quiet=quiet, detail=True)
            cur = bal.uv
            for k in range(MAX_RESTARTS + 1):
                r = attempt(cur, "balanced" if k == 0 else f"balanced, moved {k}x", max_iterations=600)
                if r is not None and (best is None or r.residual < best[0].residual):
                    best, restarts = (r, cur, "balanced"), k
                if r is None or r.converged or k == MAX_RESTARTS:
                    break
                # start again from the map the solve reached: its centroids, made fold-free, are
                # sites whose cells are closer to their masses than the last ones'
                try:
                    cur = convex_combination_map(F, _snap(r.centroid, bnd, sides), cur).uv
                except ParameterizationError:
                    break
        ot, sites_uv, sites = best if best is not None else (None, uv, "conformal")
        if ot is not None and ot.merged:
            import warnings

            from ..errors import GeofaceWarning

            warnings.warn(f"{ot.merged} vertices lie on top of each other in the map; they share a cell (and a centroid; "
                          "the fold-free step separates them)", GeofaceWarning, stacklevel=2)
        result = None
        if ot is not None:
            result = _from_centroids(F, V, ot, bnd, sides, orient, sites_uv, fold_free, quiet)
        if bal is not None and (result is None or not ot.converged):
            # OT did not reach tol from any sites: the balanced embedding if it is closer
            bal_res = _max_rel_area_error(F, bal.uv, nu)
            if result is None or bal_res < ot.residual:
                result = (bal.uv, 0, 0, None, area_error(F, bal.uv, nu), area_error(F, bal.uv, nu))
                ot, sites = None, "balanced"
        new, flipped_before, flipped_after, ff, err_before, err_after = result
        residual = float(ot.residual) if ot is not None else _max_rel_area_error(F, new, nu)
        if residual > tol:
            log(f"  measure-preserving map: reached max relative area error {residual:.3g} (tolerance {tol:g})", quiet=quiet, detail=True)
        share = None
        if roi is not None:
            fa = np.abs(signed_uv_areas(F, new))
            in_roi = roi.astype(bool)[F].all(1)
            share = float(fa[in_roi].sum() / fa.sum())
        if ot is not None and sites == "conformal":
            self._warm = (uv.copy(), np.asarray(ot.h, np.float64).copy())
        return MeasureMapResult(
            uv=new, ot=ot, flipped_before=flipped_before, flipped_after=flipped_after, seconds=time.perf_counter() - t0,
            fold_free=ff, area_error_before=err_before, area_error_after=err_after, roi_share=share, sites=sites, balanced=bal,
            attempts=attempts, residual=residual, converged=residual <= tol, restarts=restarts,
        )


def measure_preserving_map(
    V,
    F,
    uv,
    *,
    roi=None,
    lam: float = 2.5,
    blend: float = 0.0,
    feature: float = 0.0,
    tol: float = 1e-3,
    fold_free: bool = True,
    h0=None,
    linear_solver: str = "auto",
    backend: str = "auto",
    quiet: bool | None = None,
) -> MeasureMapResult:
    """Measure-preserving map from a map ``uv`` of the disk ``(V, F)`` onto the unit square.

    Parameters
    ----------
    uv : (n, 2) in [0, 1]^2 with the boundary on the square's sides (e.g.
        ``RicciFlowResult.unit_square()``)
    roi : (n,) bool vertex mask of the region of interest (e.g. the face) or None
    lam : mass factor on the region of interest (the paper: 2.5); 1 = area-preserving
    blend : share β of the starting map's own area in the masses (module docs); 0 = the paper's
    feature : γ, the extra mass on sharp spots (module docs); 0 = the paper's
    tol : OT tolerance, max |w_i - ν_i| / ν_i
    fold_free : replace the centroid map by the fold-free convex-combination map (default);
        False returns the centroids (snapped to the sides), which may fold
    backend : power-diagram construction (``"auto"``, ``"cgal"``, ``"qhull"``)
    """
    return MeasurePreservingSolver(V, F, tol=tol, fold_free=fold_free, linear_solver=linear_solver, backend=backend,
                                   quiet=quiet).solve(uv, roi=roi, lam=lam, blend=blend, feature=feature, h0=h0)


def _max_rel_area_error(F, uv, nu) -> float:
    """max |a_i / ν_i - 1| of the per-vertex areas (both normalised)."""
    return float(np.max(np.abs(np.expm1(log_area_ratio(F, uv, nu)))))


def _from_centroids(F, V, ot, bnd, sides, orient, reference, fold_free, quiet):
    """The centroid map snapped to the sides, its folds replaced by the fold-free step (whose
    reference, around the folds, is the sites' own fold-free map); an untangled map is relaxed
    towards the centroids' areas (:mod:`geoface.param.relax`)."""
    new = _snap(ot.centroid, bnd, sides)
    flipped_before = int((orient * signed_uv_areas(F, new) <= 0).sum())
    err_before = area_error(F, new, ot.nu)
    ff = None
    if fold_free and flipped_before:
        from .relax import relax_map, triangle_targets

        inner = np.ones(len(new), bool)
        inner[bnd] = False
        T = triangle_targets(V, F, ot.nu)

        def refine(x):
            xr, info = relax_map(F, x, new, T, movable=inner, orient=orient)
            logging.getLogger("geoface").debug("relax: %d iterations, energy %.3g -> %.3g", info["iterations"],
                                               info["energy_before"] or 0.0, info["energy_after"] or 0.0)
            return xr
        try:
            ff = convex_combination_map(F, new, reference, refine=refine, score=lambda x: area_error(F, x, ot.nu))
        except ParameterizationError:  # rounding on near-degenerate triangles: the sites' map, which cannot fold
            ff = None
            new = reference.copy()
        else:
            new = ff.uv
            log(f"  measure-preserving map: {flipped_before} folded triangles of the centroid map replaced "
                f"({ff.fitted_vertices} vertices re-fitted)", quiet=quiet, detail=True)
    flipped_after = int((orient * signed_uv_areas(F, new) <= 0).sum())
    return new, flipped_before, flipped_after, ff, err_before, area_error(F, new, ot.nu)
