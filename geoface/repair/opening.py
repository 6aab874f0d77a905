"""Opening closed surfaces: cut at a plane (default: the neck, lowest along the up axis)
or remove a geodesic cap, so that a disk boundary appears.

>>> from geoface.synth import sphere
>>> V, F = sphere(1.0, 3)
>>> res = open_at_plane(V, F, up=(0, 0, 1), height=0.1)
>>> from geoface.mesh import topology_report
>>> topology_report(res.V, res.F).boundary_loops
1
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..errors import InvalidMeshError, MeshTopologyError
from ..mesh.core import check_mesh, edge_topology, face_areas
from .clean import merge_vertices
from .step import StepResult, match_provenance, select_faces

def as_axis(up) -> np.ndarray:
    """Unit vector from ``"x" | "+y" | "-z" ...``, three numbers (``"0,0,1"``) or a 3-vector:
    the same values every ``--up`` takes (:func:`geoface.mesh.frame.parse_up`)."""
    from ..errors import GeofaceError
    from ..mesh.frame import parse_up

    if up is None:
        raise InvalidMeshError("up must be an axis or a 3-vector; got None")
    try:
        return parse_up(up)
    except (GeofaceError, TypeError, ValueError) as e:
        raise InvalidMeshError(str(e) if isinstance(e, GeofaceError) else f"up must be a non-zero 3-vector; got {up!r}") from None


def open_at_plane(V, F, *, up="y", height: float = 0.02, origin=None) -> StepResult:
    """Cut away everything below a plane whose normal is ``up``.

    Parameters
    ----------
    up : axis name or 3-vector; the kept side is the one ``up`` points to
    height : float
        Plane position as a fraction of the mesh's extent along ``up``, from its lowest
        point (default 0.02: just above the bottom, i.e. the neck of an upright head).
    origin : 3-vector, optional
        A point on the plane; overrides ``height``.

    Notes
    -----
    Triangles crossing the plane are split exactly (trimesh), so the new boundary is a
    planar curve.  The result may have several loops or components (e.g. four hooves);
    :func:`geoface.repair.make_disk` keeps the largest part and fills the other loops.
    """
    from trimesh.intersections import slice_faces_plane

    V, F = check_mesh(V, F)
    n = as_axis(up)
    h = V @ n
    if origin is None:
        if not (0.0 < height < 1.0):
            raise InvalidMeshError(f"height must be a fraction in (0, 1); got {height!r}")
        o = n * (h.min() + height * (h.max() - h.min()))
    else:
        o = np.asarray(origin, np.float64).reshape(3)
    V1, F1, _ = slice_faces_plane(V, F, plane_normal=n, plane_origin=o)
    if len(F1) == 0:
        raise MeshTopologyError("the cutting plane removes the whole mesh")
    res = match_provenance(V, F, np.asarray(V1, np.float64), np.asarray(F1, np.int64))
    # trimesh makes one intersection point per cut triangle: weld them along the cut
    res = res.then(merge_vertices(res.V, res.F))
    area_removed = float(face_areas(V, F).sum() - face_areas(res.V, res.F).sum())
    change = {"step": "open_plane", "origin": [float(x) for x in o], "normal": [float(x) for x in n], "area_removed": area_removed}
    return StepResult(res.V, res.F, res.vertex_map, res.face_map, [change])


def open_with_cap(V, F, *, up="y", center: int | None = None, area_fraction: float = 0.02) -> StepResult:
    """Remove a geodesic cap of ``area_fraction`` of the surface around ``center``.

    ``center`` defaults to the lowest vertex along ``up``.  Geodesic distance is
    approximated by shortest paths along edges (Dijkstra).
    """
    V, F = check_mesh(V, F)
    if not (0.0 < area_fraction < 0.5):
        raise InvalidMeshError(f"area_fraction must be in (0, 0.5); got {area_fraction!r}")
    if center is None:
        used = np.unique(F)
        center = int(used[np.argmin(V[used] @ as_axis(up))])
    elif not (0 <= int(center) < len(V)):
        raise InvalidMeshError(f"center must be a vertex index in [0, {len(V)}); got {center!r}")
    et = edge_topology(F)
    E = et.E
    w = np.maximum(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1), 1e-300)
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
    dist = dijkstra(G, directed=False, indices=int(center))
    fd = dist[F].max(1)
    A = face_areas(V, F)
    order = np.argsort(fd, kind="stable")
    cum = np.cumsum(A[order])
    k = int(np.searchsorted(cum, area_fraction * cum[-1]))
    radius = fd[order[min(k, len(order) - 1)]]
    keep = fd > radius
    if keep.all() or not keep.any():
        raise MeshTopologyError("could not remove a cap of the requested size")
    change = {"step": "open_cap", "center": int(center), "radius": float(radius), "area_removed": float(A[~keep].sum())}
    return select_faces(V, F, keep, [change])
