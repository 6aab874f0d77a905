"""Plain-array mesh primitives: validation, areas, edges, loops, components, vertex fans.

Conventions (DESIGN.md): ``V`` float64 ``(n, 3)``, ``F`` int64 ``(m, 3)``, counter-clockwise.
Half-edge ``h = 3*f + k`` runs from ``F[f, k]`` to ``F[f, (k+1) % 3]``; corner ``c = 3*f + k``
is vertex ``F[f, k]`` seen from face ``f``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..tol import tol


from .checks import CHECKED_SCOPE, TOPOLOGY_CACHE_SIZE, CHECKS, MAX_COORDINATE, check_mesh, checked_meshes  # noqa: F401  (public here too)


def bbox_diagonal(V: np.ndarray) -> float:
    """Length of the bounding-box diagonal (1.0 for an empty or single-point set)."""
    if len(V) == 0:
        return 1.0
    d = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    return d if d > 0 else 1.0


def face_normals_unnormalized(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Cross products ``(v1 - v0) x (v2 - v0)``: direction = normal, length = 2 * area."""
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def face_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Triangle areas, ``(m,)`` float64."""
    return 0.5 * np.linalg.norm(face_normals_unnormalized(V, F), axis=1)


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit face normals ``(m, 3)`` (zero for degenerate faces)."""
    N = face_normals_unnormalized(V, F)
    L = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, L, out=np.zeros_like(N), where=L > 0)


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric vertex areas: one third of the adjacent face areas, ``(n,)``."""
    A = face_areas(V, F) / 3.0
    return np.bincount(F.ravel(), weights=np.repeat(A, 3), minlength=len(V))


def uv_vertex_areas(F: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """:func:`vertex_areas` of a planar map ``uv`` ``(n, 2)``: one third of the adjacent
    triangles' absolute areas in the plane."""
    uv = np.asarray(uv, np.float64)
    return vertex_areas(np.column_stack([uv, np.zeros(len(uv))]), F)


def vertex_adjacency(F: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """Symmetric 0/1 vertex adjacency ``(n, n)`` float64 (vertices sharing an edge)."""
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n_vertices, n_vertices))
    A.data[:] = 1.0
    return A


def vertex_face_incidence(F: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """``(n, m)`` 0/1 matrix: row ``v`` lists the faces around vertex ``v`` (``.indices``)."""
    return sp.csr_matrix((np.ones(F.size), (F.ravel(), np.repeat(np.arange(len(F)), 3))), shape=(n_vertices, len(F)))


def signed_uv_areas(F: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Signed areas ``(m,)`` of the triangles ``F`` in 2D coordinates ``uv`` (> 0: counter-clockwise)."""
    a = uv[F[:, 1]] - uv[F[:, 0]]
    b = uv[F[:, 2]] - uv[F[:, 0]]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(n, 3)``."""
    N = face_normals_unnormalized(V, F)
    out = np.zeros((len(V), 3))
    for k in range(3):
        np.add.at(out, F[:, k], N)
    L = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, L, out=np.zeros_like(out), where=L > 0)


@dataclass(frozen=True)
class EdgeTopology:
    """Undirected edges and their incidence with half-edges.

    Attributes
    ----------
    E : (k, 2) int64, sorted vertex pairs (``E[:, 0] < E[:, 1]``)
    he_edge : (3m,) int64, edge of each half-edge
    edge_faces : (k,) int64, number of faces on each edge
    he_src, he_dst : (3m,) int64, start and end vertex of each half-edge
    """

    E: np.ndarray
    he_edge: np.ndarray
    edge_faces: np.ndarray
    he_src: np.ndarray
    he_dst: np.ndarray

    @property
    def boundary_halfedges(self) -> np.ndarray:
        return np.flatnonzero(self.edge_faces[self.he_edge] == 1)

    @property
    def nonmanifold_edges(self) -> np.ndarray:
        return np.flatnonzero(self.edge_faces > 2)


def edge_topology(F: np.ndarray) -> EdgeTopology:
    """Build :class:`EdgeTopology` for faces ``F`` (vectorised, int64 edge keys). Inside
    :func:`checked_meshes` the same faces get the same (read-only) topology back, built once."""
    cache = CHECKED_SCOPE.get()
    if cache is None or len(F) == 0:
        return _edge_topology(F)
    F = np.ascontiguousarray(F)
    key = (F.shape, F.dtype.str, hashlib.blake2b(F.view(np.uint8), digest_size=16).digest())
    et = cache.get(key)
    if et is None:
        et = _edge_topology(F.copy())
        for a in (et.E, et.he_edge, et.edge_faces, et.he_src, et.he_dst):
            a.flags.writeable = False
        if len(cache) >= TOPOLOGY_CACHE_SIZE:
            cache.pop(next(iter(cache)))
        cache[key] = et
    return et


def _edge_topology(F: np.ndarray) -> EdgeTopology:
    CHECKS.topologies += 1
    src = F.ravel()
    dst = F[:, [1, 2, 0]].ravel()
    if len(src) == 0:
        return EdgeTopology(np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), src, dst)
    n = np.int64(src.max()) + 1
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    keys, he_edge = np.unique(lo * n + hi, return_inverse=True)
    E = np.stack([keys // n, keys % n], 1)
    he_edge = he_edge.ravel().astype(np.int64)
    counts = np.bincount(he_edge, minlength=len(E))
    return EdgeTopology(E.astype(np.int64), he_edge, counts, src, dst)


#: undirected edge key ``min * EDGE_KEY + max`` (vertex counts below 2^31)
EDGE_KEY = np.int64(1) << 31


def edge_keys(F: np.ndarray) -> np.ndarray:
    """Sorted undirected edge keys of faces ``F`` (for :func:`has_edge`)."""
    a = F.ravel()
    b = F[:, [1, 2, 0]].ravel()
    return np.unique(np.minimum(a, b) * EDGE_KEY + np.maximum(a, b))


def has_edge(keys: np.ndarray, a, b) -> np.ndarray:
    """Whether the undirected edges ``a``-``b`` are among ``keys`` (from :func:`edge_keys`)."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    k = np.minimum(a, b) * EDGE_KEY + np.maximum(a, b)
    pos = np.clip(np.searchsorted(keys, k), 0, max(len(keys) - 1, 0))
    return (keys[pos] == k) if len(keys) else np.zeros(k.shape, bool)


def manifold_halfedge_pairs(et: EdgeTopology) -> np.ndarray:
    """``(p, 2)`` pairs of half-edges on edges shared by exactly two faces."""
    order = np.argsort(et.he_edge, kind="stable")
    e_sorted = et.he_edge[order]
    two = et.edge_faces[e_sorted] == 2
    h = order[two]
    # consecutive entries of the same edge come in pairs after the stable sort
    return h.reshape(-1, 2)


def accumulate_to_root(parent: np.ndarray, values: np.ndarray, combine=np.add) -> np.ndarray:
    """Combine ``values`` along every node's path to the root of a forest, vectorised.

    ``parent[i]`` is the parent of node ``i`` (roots are their own parent, with the
    identity value).  Pointer jumping: O(log depth) rounds of whole-array operations.
    ``combine=np.add`` gives depths (values 1 off the roots); ``np.bitwise_xor`` parities.
    """
    acc = np.array(values, copy=True)
    P = np.asarray(parent).copy()
    while True:
        nxt = P[P]
        if np.array_equal(nxt, P):
            return acc
        acc = combine(acc, acc[P])
        P = nxt


def halfedge_twins(F: np.ndarray) -> np.ndarray:
    """``(3m,)`` twin of every half-edge on an edge with exactly two faces, else -1."""
    pairs = manifold_halfedge_pairs(edge_topology(F))
    twin = -np.ones(3 * len(F), np.int64)
    twin[pairs[:, 0]] = pairs[:, 1]
    twin[pairs[:, 1]] = pairs[:, 0]
    return twin


def corner_of(F: np.ndarray, faces: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Corner index ``3*f + k`` of vertex ``verts[i]`` in face ``faces[i]``."""
    k = np.argmax(F[faces] == verts[:, None], axis=1)
    return 3 * faces + k


def vertex_fans(F: np.ndarray, pairs: np.ndarray) -> tuple[int, np.ndarray]:
    """Group the corners around each vertex into fans connected through paired half-edges.

    Two corners of the same vertex belong to one fan when their faces are linked by a
    pair in ``pairs`` across an edge incident to that vertex.  A manifold vertex has one
    fan; a non-manifold ("bow-tie") vertex has several.

    Returns
    -------
    n_fans : int
    labels : (3m,) int64, fan id of each corner
    """
    m = len(F)
    if len(pairs) == 0:
        return 3 * m, np.arange(3 * m)
    h1, h2 = pairs[:, 0], pairs[:, 1]
    f1, f2 = h1 // 3, h2 // 3
    src = F.ravel()
    dst = F[:, [1, 2, 0]].ravel()
    a, b = src[h1], dst[h1]
    rows = np.concatenate([corner_of(F, f1, a), corner_of(F, f1, b)])
    cols = np.concatenate([corner_of(F, f2, a), corner_of(F, f2, b)])
    G = sp.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(3 * m, 3 * m))
    return connected_components(G, directed=False)


def nonmanifold_vertices(F: np.ndarray, n_vertices: int, et: EdgeTopology | None = None) -> np.ndarray:
    """Vertices whose corners form more than one fan (bow-ties, or touching a >2-face edge)."""
    et = et if et is not None else edge_topology(F)
    _, labels = vertex_fans(F, manifold_halfedge_pairs(et))
    corner_vertex = F.ravel()
    fan_vertex = np.zeros(labels.max() + 1 if len(labels) else 0, np.int64)
    fan_vertex[labels] = corner_vertex
    fans_per_vertex = np.bincount(fan_vertex, minlength=n_vertices)
    return np.flatnonzero(fans_per_vertex > 1)


def boundary_loops(F: np.ndarray, et: EdgeTopology | None = None) -> list[np.ndarray]:
    """Boundary loops as arrays of vertex indices, in the direction of their half-edges.

    On an oriented mesh each loop ``L`` has half-edges ``L[i] -> L[i+1]`` in ``F`` (the
    surface lies to the left when walking along it, seen from outside).  On a badly
    oriented or non-orientable mesh a loop may have to walk some half-edges backwards.
    Where a vertex has several boundary edges (a non-manifold boundary vertex) the
    pairing is arbitrary, but every boundary edge is used exactly once.
    """
    et = et if et is not None else edge_topology(F)
    bh = et.boundary_halfedges
    if len(bh) == 0:
        return []
    src, dst = et.he_src[bh], et.he_dst[bh]
    nb = len(bh)
    # incidence lists: boundary edge ids leaving (forward) or entering (backward) each vertex
    out_order = np.argsort(src, kind="stable")
    in_order = np.argsort(dst, kind="stable")
    out_sorted, in_sorted = src[out_order], dst[in_order]
    used = np.zeros(nb, bool)

    def take(v: int, order: np.ndarray, keys: np.ndarray) -> int:
        lo, hi = np.searchsorted(keys, v, "left"), np.searchsorted(keys, v, "right")
        for s in range(lo, hi):
            e = int(order[s])
            if not used[e]:
                return e
        return -1

    loops = []
    for e0 in range(nb):
        if used[e0]:
            continue
        loop = [int(src[e0])]
        used[e0] = True
        v = int(dst[e0])
        while v != loop[0]:
            loop.append(v)
            e = take(v, out_order, out_sorted)
            if e >= 0:
                used[e] = True
                v = int(dst[e])
                continue
            e = take(v, in_order, in_sorted)
            if e < 0:  # open chain (cannot happen on a proper boundary); stop here
                break
            used[e] = True
            v = int(src[e])
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def loop_length(V: np.ndarray, loop: np.ndarray) -> float:
    """Geometric length of a closed vertex loop."""
    P = V[loop]
    return float(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1).sum())


def face_components(F: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of faces sharing a vertex.

    Returns ``(count, face_labels)`` with ``face_labels`` of shape ``(m,)``.
    """
    m = len(F)
    if m == 0:
        return 0, np.zeros(0, np.int64)
    rows = np.concatenate([F[:, 0], F[:, 1]])
    cols = np.concatenate([F[:, 1], F[:, 2]])
    G = sp.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    _, vlab = connected_components(G, directed=False)
    flab = vlab[F[:, 0]]
    uniq, face_labels = np.unique(flab, return_inverse=True)
    return len(uniq), face_labels.ravel()


def edge_adjacent_components(F: np.ndarray, pairs: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of faces linked by the half-edge ``pairs``."""
    m = len(F)
    f1, f2 = pairs[:, 0] // 3, pairs[:, 1] // 3
    G = sp.coo_matrix((np.ones(len(f1), np.int8), (f1, f2)), shape=(m, m))
    return connected_components(G, directed=False)


def remove_unreferenced(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop vertices no face uses. Returns ``(V, F, kept)`` with ``kept`` the old indices."""
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    kept = np.flatnonzero(used)
    remap = -np.ones(len(V), np.int64)
    remap[kept] = np.arange(len(kept))
    return V[kept], remap[F], kept


def degenerate_faces(V: np.ndarray, F: np.ndarray, diag: float | None = None) -> np.ndarray:
    """Boolean mask of faces with a repeated vertex index or (relative) zero area."""
    diag = bbox_diagonal(V) if diag is None else diag
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    return rep | (face_areas(V, F) <= tol.area_eps * diag * diag)


#: below this many vertices ``(a n + b) n + c`` fits int64 (2^21 = 2,097,152; n³ < 2^63)
TRIPLE_KEY_LIMIT = 2_097_151


def triple_keys(*rows: np.ndarray, n: int) -> list[np.ndarray]:
    """int64 keys of ``(k, 3)`` index rows (entries below ``n``), equal exactly where two rows
    are, across all the arrays given: ``(a n + b) n + c`` up to :data:`TRIPLE_KEY_LIMIT`
    vertices, which would overflow above it; row ids of one joint ``np.unique`` beyond."""
    rows = [np.asarray(r, np.int64).reshape(-1, 3) for r in rows]
    if n <= TRIPLE_KEY_LIMIT:
        n = np.int64(n)
        return [(r[:, 0] * n + r[:, 1]) * n + r[:, 2] for r in rows]
    _, inv = np.unique(np.concatenate(rows), axis=0, return_inverse=True)
    return np.split(inv.ravel().astype(np.int64), np.cumsum([len(r) for r in rows])[:-1])


def duplicate_faces(F: np.ndarray) -> np.ndarray:
    """Boolean mask of faces whose vertex set repeats an earlier face (first one kept)."""
    if len(F) == 0:
        return np.zeros(0, bool)
    key = np.sort(F, axis=1)
    _, first = np.unique(triple_keys(key, n=int(key.max()) + 1)[0], return_index=True)
    dup = np.ones(len(F), bool)
    dup[first] = False
    return dup


def double_sided_faces(F: np.ndarray) -> np.ndarray:
    """Boolean mask of faces whose vertex set also occurs with the opposite orientation (a
    triangle and its reverse: a sheet of zero thickness, as fins and double-sided exports make)."""
    if len(F) == 0:
        return np.zeros(0, bool)
    F = np.asarray(F, np.int64)
    order = np.argsort(F, axis=1)
    key = np.take_along_axis(F, order, 1)
    # the orientation: whether sorting the corners is an even permutation (a rotation) or odd
    even = ((order[:, 0] < order[:, 1]) ^ (order[:, 1] < order[:, 2]) ^ (order[:, 0] < order[:, 2])).astype(np.int8)
    _, inv = np.unique(triple_keys(key, n=int(key.max()) + 1)[0], return_inverse=True)
    inv = inv.ravel()
    both = np.zeros(inv.max() + 1, np.int8)
    np.bitwise_or.at(both, inv, np.where(even == 1, 1, 2).astype(np.int8))
    return both[inv] == 3


def signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume enclosed by a closed, consistently oriented mesh (positive = outward)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
