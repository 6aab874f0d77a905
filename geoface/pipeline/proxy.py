"""Large scans through a decimated proxy (:func:`geoface.pipeline.convert` with ``proxy``): the
repair, Ricci flow and optimal transport run on the proxy; every pixel of the images then takes
its position, normal and colour from the closest point of the full-resolution surface, so no
detail of the scan is lost, and the error report measures against the full surface.

The full surface here is the part of the scan the repaired proxy stands for: the scan's faces
whose vertices all lie within ``tol`` (the proxy's mean edge length) of the proxy disk.  Debris
the repair removed, what lies below a neck cut, and faces far from a filled hole are not part of
it; a pixel whose closest full-surface point is further than ``tol`` (inside a hole the repair
filled) keeps the proxy's position; a pixel closer to a face the repair created (a filled hole,
a neck cap) than to the scan moves onto that face instead.  The error report measures against the full
surface and those faces, as it measures against the repaired disk without a proxy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..mesh.core import bbox_diagonal, vertex_normals
from ..mesh.mesh_data import Mesh

__all__ = ["FullSurface", "full_surface"]


@dataclass
class FullSurface:
    """The full-resolution surface under a proxy (see module docs)."""

    mesh: Mesh
    F: np.ndarray                 # the scan's faces the proxy disk stands for
    query: object                 # geoface.uvmap.SurfaceQuery over (mesh.V, F)
    normals: np.ndarray           # the scan's vertex normals (over those faces)
    tol: float
    diag: float
    roi: np.ndarray | None        # the ROI carried onto the scan's vertices
    kept: np.ndarray              # scan vertices in F
    colour_source: Mesh | None    # the scan's colours over F (vertex colours or UV + texture)
    seconds: dict = field(default_factory=dict)
    # the faces the repair created on the proxy disk (filled holes, a neck cap): a query over
    # them (pixels move onto them when they are closer than the scan; the error report measures
    # against them too) and their vertices
    fill_query: object = None
    fill_vertices: np.ndarray | None = None
    #: (:meth:`sample`) the last sampled positions and their distances to the scan and the fills
    last_points: np.ndarray | None = None
    last_distance: np.ndarray | None = None

    def sample(self, P: np.ndarray, N_proxy: np.ndarray):
        """Positions, normals and colours (or None) for proxy surface points ``P (k, 3)`` (with
        the proxy's normals there), and the share of points that moved onto the scan. Each
        position's distance to the scan and the fills is kept in ``last_distance``: 0 where it
        moved onto them (it is their closest point), the proxy point's own elsewhere; the positions in
        ``last_points``."""
        dist, face, bary = self.query(P)
        Q = self.query.points(face, bary)
        on_scan = dist <= self.tol
        if self.fill_query is not None:  # onto the scan or a fill, whichever is closer: a fill keeps its place
            d_fill, f_fill, b_fill = self._fill_near(P, dist)
            to_fill = (d_fill < dist) & (d_fill <= self.tol)
            on_scan &= ~to_fill
            Q = np.where(to_fill[:, None], self.fill_query.points(f_fill, b_fill), Q)
            keep = ~on_scan & ~to_fill
            dist = np.minimum(dist, d_fill)
        else:
            keep = ~on_scan
        Q = np.where(keep[:, None], P, Q)
        self.last_distance = np.where(keep, dist, 0.0)
        self.last_points = Q
        n = (self.normals[self.F[face]] * bary[:, :, None]).sum(1)
        Nn = np.where(on_scan[:, None], n, N_proxy)
        snap = on_scan
        C = None
        if self.colour_source is not None:
            from ..uvmap.bake import sample_source

            C = sample_source(self.colour_source, face, bary, "color")
        return Q, Nn, C, float(snap.mean()) if len(snap) else 1.0

    def _fill_near(self, P, dist):
        """The fills' closest points to ``P`` where :meth:`sample` can use them: every point within
        ``tol`` of the fills' bounding box, and every point further than ``tol`` from the scan (its
        distance is the smaller of the two); elsewhere the fills are further than ``tol`` and not
        nearer than the scan, and their distance is left infinite (a fill is small beside the
        pixels: most need no query)."""
        lo, hi = self.fill_vertices.min(0) - self.tol, self.fill_vertices.max(0) + self.tol
        ask = np.flatnonzero(((P >= lo) & (P <= hi)).all(1) | (dist > self.tol))
        d = np.full(len(P), np.inf)
        f = np.zeros(len(P), np.int64)
        b = np.zeros((len(P), 3))
        b[:, 0] = 1.0
        if len(ask):
            d[ask], f[ask], b[ask] = self.fill_query(P[ask])
        return d, f, b

    def error(self, V_rec, F_rec, rec_mask=None, sampled: bool = False) -> dict:
        """Two-sided distances between a reconstruction and this surface, with the faces the
        repair created (filled holes, a neck cap) from the proxy disk, over its diagonal (the
        keys of :func:`geoface.pipeline.corner_set.reconstruction_error`). ``sampled``: True when
        the reconstruction's vertices are the positions :meth:`sample` gave last, in its order (as
        stored: a vertex is within its distance from there of the surface, the distance of its
        sampled point plus how far storing moved it: no query needed)."""
        from ..uvmap.bake import SurfaceQuery

        if sampled and self.last_points is not None and len(self.last_points) == len(V_rec):
            d_rec = (self.last_distance + np.linalg.norm(np.asarray(V_rec, np.float64) - self.last_points, axis=1)) / self.diag
        else:
            d_rec = self.query(V_rec)[0] / self.diag
            if self.fill_query is not None:
                d_rec = np.minimum(d_rec, self.fill_query(V_rec)[0] / self.diag)
        rec = SurfaceQuery(V_rec, F_rec)
        d_ref = rec(self.mesh.V[self.kept])[0] / self.diag
        d_fill = rec(self.fill_vertices)[0] / self.diag if self.fill_vertices is not None else np.zeros(0)
        d_all = np.concatenate([d_ref, d_fill])
        out = {"hausdorff": float(max(d_rec.max(), d_all.max())), "mean": float(0.5 * (d_rec.mean() + d_all.mean())),
               "rec_to_ref_max": float(d_rec.max()), "ref_to_rec_max": float(d_all.max()), "reference": "full scan"}
        if self.roi is not None and rec_mask is not None and rec_mask.any() and self.roi[self.kept].any():
            a, b = d_rec[rec_mask], d_ref[self.roi[self.kept]]
            out["face_hausdorff"] = float(max(a.max(), b.max()))
            out["face_mean"] = float(0.5 * (a.mean() + b.mean()))
        return out


def _near_boundary(F: np.ndarray, face: np.ndarray) -> np.ndarray:
    """Whether each face index ``face`` of the mesh ``F`` has a vertex on the boundary."""
    from ..mesh.core import boundary_loops

    on = np.zeros(int(F.max()) + 1, bool)
    for lp in boundary_loops(F):
        on[lp] = True
    return on[F[face]].any(1)


def full_surface(mesh: Mesh, V_disk: np.ndarray, F_disk: np.ndarray, roi_disk: np.ndarray | None,
                 fill: np.ndarray | None = None, faces: np.ndarray | None = None) -> FullSurface | None:
    """The scan ``mesh`` as the full surface under the proxy disk ``(V_disk, F_disk)`` (see
    module docs); ``roi_disk`` (over the proxy disk's vertices) is carried onto the scan.
    ``fill``: which faces of the disk the repair created (they have no scan under them; the
    error report measures against them, as it does without a proxy).  None when no face of the
    scan lies within ``tol`` of the proxy.  ``faces``: the scan's faces the disk stands for, when
    the caller knows them (a proxy that only merged vertices), instead of those within ``tol``."""
    from ..uvmap.bake import SurfaceQuery

    t0 = time.perf_counter()
    E = np.concatenate([F_disk[:, [0, 1]], F_disk[:, [1, 2]], F_disk[:, [2, 0]]])
    tol = float(np.linalg.norm(V_disk[E[:, 0]] - V_disk[E[:, 1]], axis=1).mean())
    d, face, bary = SurfaceQuery(V_disk, F_disk)(mesh.V)
    # beyond the proxy's boundary (below a neck cut) the closest proxy point is in a triangle at
    # the boundary: there only what lies on the proxy counts (a tenth of tol: the decimation's own
    # deviation), not a strip of the scan a whole edge wide
    # so too next to a face the repair created: what a neck cap or a filled hole closes off
    # (the bottom of a leg cut by the opening plane) is not part of it
    strict = _near_boundary(F_disk, face)
    if fill is not None:
        strict |= fill[face]
    near = d <= np.where(strict, 0.1 * tol, tol)
    keep_f = np.flatnonzero(near[mesh.F].all(1)) if faces is None else np.asarray(faces, np.int64)
    if not len(keep_f):
        return None
    F = mesh.F[keep_f]
    kept = np.zeros(len(mesh.V), bool)
    kept[F.ravel()] = True
    t1 = time.perf_counter()
    q = SurfaceQuery(mesh.V, F)
    roi = None
    if roi_disk is not None:
        roi = (roi_disk[F_disk[face]].astype(np.float64) * bary).sum(1) > 0.5
        roi &= kept
    colours = None
    if mesh.colors is not None or (mesh.texture is not None and mesh.UV is not None):
        colours = Mesh(mesh.V, F, UV=mesh.UV, FUV=None if mesh.FUV is None else mesh.FUV[keep_f], colors=mesh.colors,
                       texture=mesh.texture)
    fills = {}
    if fill is not None and fill.any():
        Ff = F_disk[fill]
        fills = {"fill_query": SurfaceQuery(V_disk, Ff), "fill_vertices": V_disk[np.unique(Ff)]}
    return FullSurface(mesh=mesh, F=F, query=q, normals=vertex_normals(mesh.V, F), tol=tol, **fills,
                       diag=bbox_diagonal(mesh.V[kept]) if kept.any() else bbox_diagonal(mesh.V), roi=roi,
                       kept=np.flatnonzero(kept), colour_source=colours,
                       seconds={"restrict": t1 - t0, "tree": time.perf_counter() - t1})
