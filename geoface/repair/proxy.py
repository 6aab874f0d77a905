"""Proxies of a scan: the parameterization is solved on a proxy, and everything the images hold
(positions, normals, colours) is sampled from the full surface.

:func:`merge_needles` is the proxy of a scan with needle triangles (an edge far shorter than the
face's others: marching-cubes output, edges split next to their ends, near-duplicate vertices):
the short edges are collapsed, so that Ricci flow and optimal transport see well-shaped triangles
and no sites a thousandth of an edge apart.

:func:`decimate` is quadric edge collapse (fast-simplification, the pyvista project's wrapper of
Forstmann's fast quadric simplifier: a 4M-face scan in 8–14 s on one core, where pymeshlab's
quadric collapse takes 100 s); boundary edges only collapse into boundary vertices, so openings
keep their shape.

>>> from geoface.synth import sphere
>>> V, F = sphere(1.0, 4)
>>> r = decimate(V, F, 500)
>>> 400 <= len(r.V) <= 600
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._lazy import lazy_import
from ..errors import InvalidMeshError
from ..mesh.core import check_mesh

__all__ = ["decimate", "merge_needles", "ProxyResult", "NEEDLE_RATIO"]

#: an edge is a needle's short edge when it is shorter than this share of the longest edge of a
#: face it bounds (:func:`merge_needles`)
NEEDLE_RATIO = 0.01


@dataclass
class ProxyResult:
    """``V``, ``F`` of the proxy, its seconds, and (:func:`merge_needles`) how many vertices
    were merged into others."""

    V: np.ndarray
    F: np.ndarray
    seconds: float
    merged: int = 0
    #: (:func:`merge_needles`) each input vertex's proxy vertex, and each input face's proxy face
    #: (-1: it collapsed)
    vertex_of: np.ndarray | None = None
    face_of: np.ndarray | None = None


def decimate(V, F, vertices: int) -> ProxyResult:
    """Quadric edge collapse of ``(V, F)`` to about ``vertices`` vertices (within a few %);
    the mesh itself when it has no more than that."""
    import time

    V, F = check_mesh(V, F)
    if int(vertices) != vertices or vertices < 16:
        raise InvalidMeshError(f"vertices must be an integer >= 16; got {vertices!r}")
    t = time.perf_counter()
    if len(V) <= vertices:
        return ProxyResult(V, F, 0.0)
    fs = lazy_import("fast_simplification", "the proxy of a large scan")
    # faces ~ 2 × vertices on a closed or nearly closed surface; ask for the faces that give it
    target = 1.0 - min(1.0, 2.0 * vertices / max(len(F), 1))
    # the simplifier works in float32: centred first, so a scan far from the origin (millimetres,
    # metres away) keeps its precision
    c = 0.5 * (V.min(0) + V.max(0))
    # agg 9 (default 7): fewer passes, the same deviation from the scan (measured on the 2M bust:
    # max 9.7e-4 vs 9.2e-4 of the diagonal, p99 5.3e-4 for both; 8.4 s vs 11.8 s)
    V1, F1 = fs.simplify((V - c).astype(np.float32), F.astype(np.int32), target_reduction=float(np.clip(target, 0.0, 0.999)),
                         agg=9)
    V1 = np.asarray(V1, np.float64) + c
    F1 = np.asarray(F1, np.int64)
    if len(F1) == 0:
        raise InvalidMeshError("decimation left no faces")
    return ProxyResult(V1, F1, time.perf_counter() - t)


def merge_needles(V, F, ratio: float = NEEDLE_RATIO) -> ProxyResult | None:
    """``(V, F)`` with the short edges of its needle triangles collapsed, or None when it has none.

    An edge is short when it is shorter than ``ratio`` times the longest edge of a face it
    bounds.  The vertices joined by short edges form groups; each group becomes the member
    with the most faces (the lowest index among equals), faces left with a repeated vertex are
    dropped, as are repeated faces, and vertices no face uses.  A group moves the surface by at
    most its own extent, a few short edges; the images of a proxy sample the scan itself.

    >>> import numpy as np
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1e-4, 0, 0]], float)
    >>> F = np.array([[0, 4, 2], [4, 1, 2], [1, 3, 2]])
    >>> r = merge_needles(V, F)
    >>> len(r.V), len(r.F)
    (4, 2)
    """
    import time

    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from ..mesh.core import remove_unreferenced

    V, F = check_mesh(V, F)
    if not (0 < ratio < 0.5):
        raise InvalidMeshError(f"ratio must be in (0, 0.5); got {ratio!r}")
    t = time.perf_counter()
    E = np.stack([F[:, [1, 2]], F[:, [2, 0]], F[:, [0, 1]]], 1)  # (m, 3, 2): the edge opposite each corner
    L = np.linalg.norm(V[E[..., 0]] - V[E[..., 1]], axis=2)
    short = L < ratio * L.max(1, keepdims=True)
    if not short.any():
        return None
    a, b = E[short][:, 0], E[short][:, 1]
    n = len(V)
    _, label = connected_components(sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    faces_at = np.bincount(F.ravel(), minlength=n)
    # each group's representative: most faces, then the lowest index
    order = np.lexsort((np.arange(n), -faces_at, label))
    first = np.ones(n, bool)
    first[1:] = label[order][1:] != label[order][:-1]
    rep_of_label = np.empty(label.max() + 1, np.int64)
    rep_of_label[label[order][first]] = order[first]
    rep = rep_of_label[label]
    F2 = rep[F]
    alive = np.flatnonzero((F2[:, 0] != F2[:, 1]) & (F2[:, 1] != F2[:, 2]) & (F2[:, 2] != F2[:, 0]))
    if len(alive) == 0:
        raise InvalidMeshError("merging the needles' short edges left no faces")
    _, first, inv = np.unique(np.sort(F2[alive], axis=1), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # proxy faces in the order of their first input face
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    face_of = np.full(len(F), -1, np.int64)
    face_of[alive] = rank[inv.ravel()]
    F2 = F2[alive[first[order]]]
    merged = int(len(np.unique(F.ravel())) - len(np.unique(F2.ravel())))
    V2, F2, kept = remove_unreferenced(V, F2)
    index = np.full(n, -1, np.int64)
    index[kept] = np.arange(len(kept))
    return ProxyResult(V2, F2, time.perf_counter() - t, merged, vertex_of=index[rep], face_of=face_of)
