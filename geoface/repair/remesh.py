"""Remeshing / decimation to a target vertex count (pymeshlab), since every later step
scales with the number of vertices."""

from __future__ import annotations

from typing import Literal

import numpy as np

from .._lazy import lazy_import
from ..errors import InvalidMeshError
from ..mesh.core import check_mesh, face_areas
from .step import StepResult, match_provenance

Method = Literal["isotropic", "decimate"]


def _run(V, F, fn):
    pymeshlab = lazy_import("pymeshlab", "remeshing")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    fn(ms, pymeshlab)
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64)


def remesh(V, F, target_vertices: int, *, method: Method = "isotropic", iterations: int = 6) -> StepResult:
    """Bring the mesh to about ``target_vertices`` vertices.

    Parameters
    ----------
    method : "isotropic" | "decimate"
        ``isotropic`` (default): explicit isotropic remeshing to the edge length giving
        that count (well-shaped triangles, what Ricci flow wants; one correction pass);
        ``decimate``: quadric edge collapse preserving boundary and topology (keeps
        detail, only reduces).

    Notes
    -----
    The count is approximate (typically within 10%); remeshing creates new vertices,
    so the vertex map marks all vertices not at an original position as created.
    """
    V, F = check_mesh(V, F)
    if int(target_vertices) != target_vertices or target_vertices < 16:
        raise InvalidMeshError(f"target_vertices must be an integer >= 16; got {target_vertices!r}")
    if method not in ("isotropic", "decimate"):
        raise InvalidMeshError(f"method must be 'isotropic' or 'decimate'; got {method!r}")
    N = int(target_vertices)
    if method == "decimate":
        if N >= len(V):
            return StepResult.identity(V, F)

        def dec(ms, pml):
            ms.meshing_decimation_quadric_edge_collapse(
                targetfacenum=int(2 * N), preserveboundary=True, preservetopology=True, preservenormal=True, planarquadric=True, autoclean=True
            )

        V1, F1 = _run(V, F, dec)
    else:
        area = float(face_areas(V, F).sum())
        L = np.sqrt(2.0 * area / (np.sqrt(3.0) * N))
        V1 = F1 = None
        for _ in range(2):  # one correction of the edge length from the count obtained

            def iso(ms, pml, L=L):
                ms.meshing_isotropic_explicit_remeshing(iterations=int(iterations), targetlen=pml.PureValue(float(L)), featuredeg=60.0)

            V1, F1 = _run(V, F, iso)
            ratio = len(V1) / N
            if abs(ratio - 1.0) < 0.08:
                break
            L *= np.sqrt(ratio)
    res = match_provenance(V, F, V1, F1)
    change = {"step": "remesh", "method": method, "target_vertices": N, "vertices_before": int(len(V)), "vertices_after": int(len(V1))}
    return StepResult(res.V, res.F, res.vertex_map, res.face_map, [change])
