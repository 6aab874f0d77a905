"""Topology report: everything a user needs to know before parameterizing a mesh."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..tol import tol
from .core import (
    bbox_diagonal,
    boundary_loops,
    check_mesh,
    degenerate_faces,
    duplicate_faces,
    edge_topology,
    face_areas,
    face_components,
    loop_length,
    manifold_halfedge_pairs,
    nonmanifold_vertices,
)
from .orient import solve_orientation


@dataclass(frozen=True)
class TopologyReport:
    """Counts and flags describing a triangle mesh's topology.

    ``genus`` is computed per component from ``chi = 2 - 2g - b`` and summed; it is
    ``None`` when the mesh is not an orientable manifold (the formula would be meaningless).
    ``is_disk`` means: one component, manifold, consistently oriented, genus 0, one
    boundary loop.
    """

    vertices: int
    faces: int
    edges: int
    unreferenced_vertices: int
    duplicate_vertices: int
    components: int
    edge_connected_components: int
    boundary_loops: int
    boundary_loop_edges: list = field(default_factory=list)
    boundary_loop_lengths: list = field(default_factory=list)
    euler_characteristic: int = 0
    genus: int | None = None
    nonmanifold_edges: int = 0
    nonmanifold_vertices: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    consistently_oriented: bool = True
    orientable: bool = True
    inconsistent_edges: int = 0
    closed: bool = False
    manifold: bool = True
    is_disk: bool = False
    surface_area: float = 0.0
    bbox_min: list = field(default_factory=list)
    bbox_max: list = field(default_factory=list)
    bbox_diagonal: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)

    def to_json(self, **kw) -> str:
        return json.dumps(self.to_dict(), **kw)

    def format(self) -> str:
        """Human-readable multi-line summary."""
        loops = ", ".join(f"{e} edges / {ln:.4g}" for e, ln in zip(self.boundary_loop_edges, self.boundary_loop_lengths))
        genus = "n/a (not an orientable manifold)" if self.genus is None else str(self.genus)
        bmin = ", ".join(f"{x:.4g}" for x in self.bbox_min)
        bmax = ", ".join(f"{x:.4g}" for x in self.bbox_max)
        lines = [
            f"vertices            {self.vertices}  (unreferenced {self.unreferenced_vertices}, duplicate {self.duplicate_vertices})",
            f"faces               {self.faces}  (degenerate {self.degenerate_faces}, duplicate {self.duplicate_faces})",
            f"edges               {self.edges}",
            f"components          {self.components}  ({self.edge_connected_components} when joined only through edges)",
            f"boundary loops      {self.boundary_loops}" + (f"  [{loops}]" if loops else ""),
            f"euler char.         {self.euler_characteristic}",
            f"genus               {genus}",
            f"non-manifold        {self.nonmanifold_edges} edges, {self.nonmanifold_vertices} vertices",
            f"orientation         {'consistent' if self.consistently_oriented else f'{self.inconsistent_edges} inconsistent edges'}"
            + ("" if self.orientable else " (non-orientable)"),
            f"closed              {self.closed}",
            f"topological disk    {self.is_disk}",
            f"surface area        {self.surface_area:.6g}",
            f"bbox                [{bmin}] .. [{bmax}]  (diagonal {self.bbox_diagonal:.4g})",
        ]
        return "\n".join(lines)


def _edge_components(F: np.ndarray, et) -> int:
    """Components of faces joined through shared edges (any number of faces per edge)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    m = len(F)
    faces = np.arange(3 * m) // 3
    # bipartite face-edge graph: faces are nodes 0..m-1, edges m..m+k-1
    G = sp.coo_matrix((np.ones(3 * m, np.int8), (faces, m + et.he_edge)), shape=(m + len(et.E),) * 2)
    _, lab = connected_components(G, directed=False)
    return int(len(np.unique(lab[:m])))


def topology_report(V, F) -> TopologyReport:
    """Compute a :class:`TopologyReport` for mesh ``(V, F)``.

    Examples
    --------
    >>> from geoface.synth import square_grid
    >>> V, F = square_grid(4)
    >>> r = topology_report(V, F)
    >>> r.is_disk, r.genus, r.boundary_loops
    (True, 0, 1)
    """
    V, F = check_mesh(V, F)
    n, m = len(V), len(F)
    et = edge_topology(F)
    used = np.zeros(n, bool)
    used[F.ravel()] = True
    n_used = int(used.sum())
    diag = bbox_diagonal(V[used])
    pairs = manifold_halfedge_pairs(et)
    sol = solve_orientation(F, pairs)
    nm_edges = int((et.edge_faces > 2).sum())
    nm_verts = len(nonmanifold_vertices(F, n, et))
    manifold = nm_edges == 0 and nm_verts == 0
    loops = boundary_loops(F, et)
    ncomp, flab = face_components(F, n)
    chi = n_used - len(et.E) + m
    genus = None
    orientable = not bool(sol.inconsistent.any())
    if manifold and orientable:
        # per component: chi_c = V_c - E_c + F_c = 2 - 2 g_c - b_c
        vlab = np.full(n, -1)
        vlab[F.ravel()] = np.repeat(flab, 3)
        Vc = np.bincount(vlab[used], minlength=ncomp)
        Fc = np.bincount(flab, minlength=ncomp)
        Ec = np.bincount(vlab[et.E[:, 0]], minlength=ncomp)
        Bc = np.bincount(np.array([vlab[lp[0]] for lp in loops], dtype=np.int64), minlength=ncomp)
        gc = (2 - Bc - (Vc - Ec + Fc)) // 2
        genus = int(gc.sum())
    dup_v = 0
    if n_used > 1:
        tree = cKDTree(V[used])
        dup_v = len(tree.query_pairs(tol.merge * diag, output_type="ndarray"))
    lmin, lmax = V[used].min(axis=0), V[used].max(axis=0)
    consistent = not bool(sol.same_direction.any())
    return TopologyReport(
        vertices=n,
        faces=m,
        edges=len(et.E),
        unreferenced_vertices=n - n_used,
        duplicate_vertices=int(dup_v),
        components=int(ncomp),
        edge_connected_components=_edge_components(F, et),
        boundary_loops=len(loops),
        boundary_loop_edges=[int(len(lp)) for lp in loops],
        boundary_loop_lengths=[loop_length(V, lp) for lp in loops],
        euler_characteristic=int(chi),
        genus=genus,
        nonmanifold_edges=nm_edges,
        nonmanifold_vertices=nm_verts,
        degenerate_faces=int(degenerate_faces(V, F, diag).sum()),
        duplicate_faces=int(duplicate_faces(F).sum()),
        consistently_oriented=consistent,
        orientable=orientable,
        inconsistent_edges=int(sol.same_direction.sum()),
        closed=manifold and len(loops) == 0,
        manifold=manifold,
        is_disk=bool(manifold and consistent and ncomp == 1 and genus == 0 and len(loops) == 1),
        surface_area=float(face_areas(V, F).sum()),
        bbox_min=[float(x) for x in lmin],
        bbox_max=[float(x) for x in lmax],
        bbox_diagonal=float(diag),
    )
