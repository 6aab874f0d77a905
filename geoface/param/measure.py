"""Measure-preserving map of a disk onto the unit square (the head paper, after Zhao et al.).

Start from a map ``uv`` of the disk onto the unit square with the boundary on the square's
sides (the Ricci-flow rectangle, stretched).  Each vertex carries the mass
``ν_i = λ_i · ⅓ · (areas of its faces)``, with ``λ_i = lam`` on the region of interest and 1
elsewhere; semi-discrete OT gives each vertex a power cell of area ``ν_i`` and its new UV is
the cell's centroid.  So a region of interest of area share ``a`` gets ``λa / (1 + (λ-1)a)``
of the square (the face is magnified).

Two details make the result usable as a parameterization:

* Boundary vertices stay on their side of the square (a centroid lies inside its cell, a
  little off the side); corners stay at the corners.
* Centroid maps can fold a few triangles where the density changes fast.  ``untangle``
  repairs them locally: each vertex of a folded triangle moves to the centre of the kernel
  of its one-ring (the point where its triangles' smallest height is largest: a 3-variable
  linear program; boundary vertices slide along their side, corners stay), growing the set
  by a ring when that is not enough.  Every other vertex
  keeps its centroid, so cell areas change only there (the count is reported).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterizationError
from ..mesh.core import boundary_loops, check_mesh, signed_uv_areas, vertex_adjacency, vertex_areas, vertex_face_incidence
from .ot import OTResult, semi_discrete_ot

__all__ = ["MeasureMapResult", "measure_preserving_map", "signed_uv_areas", "untangle"]


@dataclass
class MeasureMapResult:
    """uv : (n, 2) the new map; ot : the OT solve; flipped_before / flipped_after : folded
    triangles before and after untangling; untangled_vertices : vertices moved by it;
    roi_share : share of the square covered by the region of interest's triangles."""

    uv: np.ndarray
    ot: OTResult
    flipped_before: int
    flipped_after: int
    untangled_vertices: int
    seconds: float
    roi_share: float | None = None


def _sides(uv: np.ndarray, bnd: np.ndarray, eps: float = 1e-9):
    """Which sides of the unit square each boundary vertex lies on: (k, 4) bool
    (x=0, x=1, y=0, y=1)."""
    p = uv[bnd]
    return np.column_stack([p[:, 0] <= eps, p[:, 0] >= 1 - eps, p[:, 1] <= eps, p[:, 1] >= 1 - eps])


def _snap(uv_new: np.ndarray, bnd: np.ndarray, sides: np.ndarray) -> np.ndarray:
    out = uv_new.copy()
    p = out[bnd]
    p[sides[:, 0], 0] = 0.0
    p[sides[:, 1], 0] = 1.0
    p[sides[:, 2], 1] = 0.0
    p[sides[:, 3], 1] = 1.0
    out[bnd] = p
    return out


def _kernel_centre(v, ring_faces, F, uv, orientation, lock=-1):
    """The point deepest inside the kernel of vertex ``v``'s one-ring (a small LP), i.e.
    where every incident triangle has the largest smallest height; None if the kernel is empty."""
    from scipy.optimize import linprog

    f = F[ring_faces]
    k = np.argmax(f == v, axis=1)
    a = uv[f[np.arange(len(f)), (k + 1) % 3]]
    b = uv[f[np.arange(len(f)), (k + 2) % 3]]
    e = (b - a) * orientation
    nrm = np.column_stack([-e[:, 1], e[:, 0]])  # left normal of a -> b: inside for positive area
    L = np.linalg.norm(nrm, axis=1)
    ok = L > 0
    nrm, a, L = nrm[ok] / L[ok, None], a[ok], L[ok]
    # maximise t subject to nrm . x - nrm . a >= t   (x in the plane, t <= scale)
    A_ub = np.column_stack([-nrm, np.ones(len(nrm))])
    b_ub = -(nrm * a).sum(1)
    scale = float(L.max())
    bounds = [(None, None), (None, None), (None, scale)]
    if lock in (0, 1):  # a boundary vertex slides along its side of the square
        bounds[lock] = (uv[v, lock], uv[v, lock])
    res = linprog(c=[0, 0, -1], A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0 or res.x[2] <= 0:
        return None
    return res.x[:2]


def untangle(F: np.ndarray, uv: np.ndarray, lock: np.ndarray, *, max_rounds: int = 80, orientation: float = 1.0):
    """Remove folded triangles by moving the vertices around them, one at a time, to the
    centre of their one-ring's kernel (a point where all their triangles are positive).

    ``lock`` (n,) int: -1 free, 0 keep x (slide along a vertical side), 1 keep y, 2 fixed
    (corners).  The set of vertices tried grows by one ring every few rounds when folds
    remain.  Returns ``(uv, moved_vertex_count)``; raises :class:`ParameterizationError` if
    folds remain.
    """
    fixed = lock == 2
    uv = uv.copy()
    n = len(uv)
    A = vertex_adjacency(F, n)
    vf = vertex_face_incidence(F, n)
    moved = np.zeros(n, bool)
    grow = np.zeros(n, bool)
    for rnd in range(max_rounds):
        bad = orientation * signed_uv_areas(F, uv) <= 0
        if not bad.any():
            return uv, int(moved.sum())
        cand = np.zeros(n, bool)
        cand[F[bad].ravel()] = True
        if rnd and rnd % 4 == 0:
            grow = grow | cand
            grow = grow | (A @ grow.astype(np.float64) > 0)
        cand = (cand | grow) & ~fixed
        for v in np.flatnonzero(cand):
            faces = vf.indices[vf.indptr[v]:vf.indptr[v + 1]]
            if not grow[v] and (orientation * signed_uv_areas(F[faces], uv) > 0).all():
                continue  # grown vertices move even when fine, to widen their neighbours' kernels
            c = _kernel_centre(v, faces, F, uv, orientation, int(lock[v]))
            if c is not None:
                uv[v] = c
                moved[v] = True
    bad = orientation * signed_uv_areas(F, uv) <= 0
    if bad.any():
        raise ParameterizationError(f"could not untangle {int(bad.sum())} folded triangles")
    return uv, int(moved.sum())


def measure_preserving_map(
    V,
    F,
    uv,
    *,
    roi=None,
    lam: float = 2.5,
    tol: float = 1e-3,
    untangle_folds: bool = True,
    h0=None,
    linear_solver: str = "auto",
    quiet: bool | None = None,
) -> MeasureMapResult:
    """Measure-preserving map from a map ``uv`` of the disk ``(V, F)`` onto the unit square.

    Parameters
    ----------
    uv : (n, 2) in [0, 1]^2 with the boundary on the square's sides (e.g.
        ``RicciFlowResult.unit_square()``)
    roi : (n,) bool vertex mask of the region of interest (e.g. the face) or None
    lam : mass factor on the region of interest (the paper: 2.5); 1 = area-preserving
    tol : OT tolerance, max |w_i - ν_i| / ν_i
    """
    t0 = time.perf_counter()
    V, F = check_mesh(V, F)
    uv = np.asarray(uv, np.float64)
    n = len(V)
    if uv.shape != (n, 2) or not np.isfinite(uv).all():
        raise ParameterizationError(f"uv must be a finite ({n}, 2) array")
    if uv.min() < -1e-9 or uv.max() > 1 + 1e-9:
        raise ParameterizationError("uv must lie in the unit square (use RicciFlowResult.unit_square())")
    if not (np.isfinite(lam) and lam > 0):
        raise ParameterizationError(f"lam must be positive; got {lam}")
    weight = np.ones(n)
    if roi is not None:
        roi = np.asarray(roi)
        if roi.shape != (n,):
            raise ParameterizationError(f"roi must be a ({n},) vertex mask; got shape {roi.shape}")
        weight = np.where(roi.astype(bool), float(lam), 1.0)
    va = vertex_areas(V, F)
    if (va <= 0).any():
        unused = int((va <= 0).sum())
        raise ParameterizationError(f"{unused} vertices have no area (unreferenced or only in degenerate faces)")
    nu = weight * va
    ot = semi_discrete_ot(uv, nu, tol=tol, h0=h0, linear_solver=linear_solver, quiet=quiet)
    if not ot.converged:
        raise ParameterizationError(f"optimal transport did not converge (max relative cell-area error {ot.residual:.3g} after {ot.iterations} iterations)")
    if ot.merged:
        import warnings

        from ..errors import GeofaceWarning

        warnings.warn(f"{ot.merged} vertices lie closer together in the input map than the power diagram can "
                      "resolve; they share a cell (and a UV before untangling)", GeofaceWarning, stacklevel=2)
    loops = boundary_loops(F)
    bnd = np.concatenate(loops) if loops else np.zeros(0, np.int64)
    sides = _sides(uv, bnd)
    if len(bnd) and not sides.any(1).all():
        raise ParameterizationError("the starting map does not put every boundary vertex on the square's sides")
    new = _snap(ot.centroid, bnd, sides)
    orient = 1.0 if signed_uv_areas(F, uv).sum() >= 0 else -1.0
    flipped_before = int((orient * signed_uv_areas(F, new) <= 0).sum())
    moved = 0
    if untangle_folds and flipped_before:
        lock = np.full(n, -1)
        on_x = sides[:, 0] | sides[:, 1]
        on_y = sides[:, 2] | sides[:, 3]
        lock[bnd[on_x]] = 0
        lock[bnd[on_y]] = 1
        lock[bnd[on_x & on_y]] = 2
        new, moved = untangle(F, new, lock, orientation=orient)
    flipped_after = int((orient * signed_uv_areas(F, new) <= 0).sum())
    share = None
    if roi is not None:
        fa = np.abs(signed_uv_areas(F, new))
        in_roi = roi.astype(bool)[F].all(1)
        share = float(fa[in_roi].sum() / fa.sum())
    return MeasureMapResult(
        uv=new, ot=ot, flipped_before=flipped_before, flipped_after=flipped_after, untangled_vertices=moved,
        seconds=time.perf_counter() - t0, roi_share=share,
    )
