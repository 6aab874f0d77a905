"""Hole filling: minimal-area triangulation, refinement to the surrounding edge length,
and bi-Laplacian fairing (in the spirit of Liepa 2003, "Filling holes in meshes").

>>> from geoface.synth import hemisphere
>>> V, F = hemisphere(1.0, 10)
>>> res = fill_holes(V, F, keep="none")     # close the hemisphere's rim
>>> len(res.F) > len(F)
True
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import InvalidMeshError, MeshTopologyError
from ..mesh.core import EDGE_KEY, boundary_loops, check_mesh, edge_keys, has_edge, loop_length
from .step import StepResult

Keep = Literal["longest", "none"]


def minimal_area_triangulation(P: np.ndarray, forbid: np.ndarray | None = None, edge_normals: np.ndarray | None = None) -> np.ndarray | None:
    """Triangulate a closed polygon ``P (n, 3)`` by dynamic programming (Liepa 2003).

    Minimises, lexicographically, the largest dihedral angle between adjacent patch
    triangles (and between patch and mesh, given ``edge_normals``), then the total area.
    The dihedral term keeps the patch from folding over a non-planar hole, which a pure
    minimal-area fill does.

    Parameters
    ----------
    P : (n, 3) array
        Polygon vertices in boundary order.
    forbid : (n, n) bool array, optional
        Chords that must not be used (edges the mesh already has).
    edge_normals : (n, 3) array, optional
        Unit normal of the mesh face on polygon edge ``(i, i+1)`` (row ``n-1``: edge
        ``(n-1, 0)``); zero rows impose nothing.

    Returns
    -------
    (n - 2, 3) int array or None
        Local indices; triangles ``(i, k, j)`` with ``i < k < j`` follow the polygon's own
        direction (the fill uses them reversed). None when every triangulation would need a
        forbidden chord.

    Notes
    -----
    O(n^3) work, vectorised over one dimension.
    """
    n = len(P)
    if n < 3:
        raise InvalidMeshError(f"a polygon needs at least 3 vertices; got {n}")
    EN = np.zeros((n, 3)) if edge_normals is None else np.asarray(edge_normals, np.float64)
    A = np.full((n, n), np.inf)  # total area of the best triangulation of i..j
    D = np.full((n, n), np.inf)  # its largest dihedral angle
    TN = np.zeros((n, n, 3))  # unit normal (fill orientation) of its top triangle
    idx = np.arange(n - 1)
    A[idx, idx + 1] = 0.0
    D[idx, idx + 1] = 0.0
    TN[idx, idx + 1] = EN[idx]  # "top triangle" of a boundary edge: the mesh face there
    K = np.zeros((n, n), np.int64)

    def dihedral(n1, n2):
        # angle between normals; zero normals (no constraint) count as flat
        c = np.clip((n1 * n2).sum(-1), -1.0, 1.0)
        known = ((n1 * n1).sum(-1) > 0.5) & ((n2 * n2).sum(-1) > 0.5)
        return np.where(known, np.arccos(c), 0.0)

    for L in range(2, n):
        i = np.arange(n - L)
        j = i + L
        t = np.arange(1, L)
        k = i[:, None] + t[None, :]
        a = P[i][:, None, :]
        cr = np.cross(P[k] - a, P[j][:, None, :] - a)
        area2 = np.linalg.norm(cr, axis=2)
        area = 0.5 * area2
        nt = -cr / np.maximum(area2, 1e-300)[..., None]  # fill orientation is reversed
        nt = np.where((area2 > 0)[..., None], nt, 0.0)
        ii = np.broadcast_to(i[:, None], k.shape)
        jj = np.broadcast_to(j[:, None], k.shape)
        dmax = np.maximum.reduce([D[ii, k], D[k, jj], dihedral(nt, TN[ii, k]), dihedral(nt, TN[k, jj])])
        dmax = np.where(area2 > 0, dmax, np.pi)  # a degenerate triangle is the worst fold
        if L == n - 1:  # the closing edge (n-1, 0) borders the mesh too
            dmax = np.maximum(dmax, dihedral(nt, EN[n - 1][None, None, :]))
        tot = A[ii, k] + A[k, jj] + area
        dbest = dmax.min(axis=1, keepdims=True)
        key = np.where(dmax <= dbest + 1e-3, tot, np.inf)
        best = np.argmin(key, axis=1)
        r = np.arange(len(i))
        A[i, j] = tot[r, best]
        D[i, j] = dmax[r, best]
        K[i, j] = k[r, best]
        TN[i, j] = nt[r, best]
        if forbid is not None and L < n - 1:
            bad = forbid[i, j]
            A[i, j] = np.where(bad, np.inf, A[i, j])
            D[i, j] = np.where(bad, np.inf, D[i, j])
    if not np.isfinite(A[0, n - 1]):
        return None
    tris = []
    stack = [(0, n - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        k = int(K[i, j])
        tris.append((i, k, j))
        stack.append((i, k))
        stack.append((k, j))
    return np.asarray(tris, np.int64)


def triangulate_loop(
    V: np.ndarray, loop: np.ndarray, edge_keys: np.ndarray | None = None, max_dp: int = 200, edge_normals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Triangles closing boundary ``loop``, oriented to match the surface.

    ``loop`` runs along the boundary half-edges, so the patch uses them reversed.
    Chords that already exist as mesh edges (``edge_keys``, from
    :func:`geoface.mesh.core.edge_keys`) are never created, as they would make the mesh
    non-manifold.  Loops longer than ``max_dp`` are first split recursively along their shortest chord
    between vertices far apart along the loop.  When no chord-free triangulation
    exists, the loop is fanned from a new centre vertex.

    ``edge_normals`` (len(loop), 3): normal of the mesh face on each loop edge (see
    :func:`minimal_area_triangulation`).

    Returns ``(faces, new_points)``: faces index ``V`` extended by ``new_points``.
    """
    loop = np.asarray(loop, np.int64)
    n = len(loop)
    nv = len(V)
    keys = edge_keys if edge_keys is not None else np.zeros(0, np.int64)
    if n <= max_dp:
        I, J = np.meshgrid(loop, loop, indexing="ij")
        forbid = has_edge(keys, I, J)
        local = minimal_area_triangulation(V[loop], forbid, edge_normals)
        if local is not None:
            return loop[local][:, ::-1], np.zeros((0, 3))
        c = nv
        fan = np.stack([np.roll(loop, -1), loop, np.full(n, c)], 1)
        return fan, V[loop].mean(0, keepdims=True)
    P = V[loop]
    stride = max(1, n // 256)
    cand_i = np.arange(0, n, stride)
    offs = np.arange(n // 4, 3 * n // 4 + 1, stride)
    I = cand_i[:, None]
    J = (I + offs[None, :]) % n
    d = np.linalg.norm(P[I] - P[J], axis=2)
    d = np.where(has_edge(keys, loop[I], loop[J]), np.inf, d)
    a, b = np.unravel_index(np.argmin(d), d.shape)
    i, j = int(cand_i[a]), int((cand_i[a] + offs[b]) % n)
    if i > j:
        i, j = j, i
    first = loop[i : j + 1]
    second = np.concatenate([loop[j:], loop[: i + 1]])
    keys2 = np.union1d(keys, [min(loop[i], loop[j]) * EDGE_KEY + max(loop[i], loop[j])])
    EN = np.zeros((n, 3)) if edge_normals is None else edge_normals
    # the chord closing each half has no known neighbour yet: a zero normal
    en1 = np.concatenate([EN[i:j], np.zeros((1, 3))])
    en2 = np.concatenate([EN[j:], EN[:i], np.zeros((1, 3))])
    t1, p1 = triangulate_loop(V, first, keys2, max_dp, en1)
    t2, p2 = triangulate_loop(V, second, keys2, max_dp, en2)
    # re-index the second half's new points after the first half's
    t2 = np.where(t2 >= nv, t2 + len(p1), t2)
    return np.concatenate([t1, t2]), np.concatenate([p1, p2])


def refine_patch(V: list, faces: list, target: float, mesh_edge_keys: np.ndarray | None = None, max_rounds: int = 12) -> tuple[list, list]:
    """Split long interior edges of a fill patch at their midpoints and flip to Delaunay.

    ``V`` is a list of 3-vectors (extended in place), ``faces`` a list of triangles
    (global indices).  Edges on the patch's border (the hole boundary) are never split,
    so the patch stays conforming with the mesh around it; flips never create an edge
    the mesh already has (``mesh_edge_keys``).
    """
    mesh_keys = mesh_edge_keys if mesh_edge_keys is not None else np.zeros(0, np.int64)
    faces = [list(f) for f in faces]
    arr = [np.asarray(V, np.float64).reshape(-1, 3)]  # V as an array, grown as V grows (not rebuilt each pass)

    def points():
        if len(arr[0]) < len(V):
            arr[0] = np.vstack([arr[0], np.asarray(V[len(arr[0]):], np.float64).reshape(-1, 3)])
        return arr[0]

    def edge_map():
        em = {}
        for fi, (a, b, c) in enumerate(faces):
            for u, v in ((a, b), (b, c), (c, a)):
                em.setdefault((min(u, v), max(u, v)), []).append(fi)
        return em

    def opposite(fi, u, v):
        a, b, c = faces[fi]
        return ({a, b, c} - {u, v}).pop()

    def directed(fi, u, v):
        a, b, c = faces[fi]
        return (a, b) == (u, v) or (b, c) == (u, v) or (c, a) == (u, v)

    def flip_pass(em):
        """One vectorised Delaunay test over all interior edges, then the flips that still apply."""
        cand = []
        for (u, v), fs in em.items():
            if len(fs) != 2:
                continue
            f1, f2 = fs
            if not directed(f1, u, v):
                f1, f2 = f2, f1
            if directed(f1, u, v) and directed(f2, v, u):
                cand.append((u, v, opposite(f1, u, v), opposite(f2, u, v), f1, f2))
        if not cand:
            return 0
        C = np.asarray(cand, np.int64)
        P = points()
        Pu, Pv, Pc, Pd = P[C[:, 0]], P[C[:, 1]], P[C[:, 2]], P[C[:, 3]]

        def ang(p, q, r):
            x, y = q - p, r - p
            return np.arctan2(np.linalg.norm(np.cross(x, y), axis=1), (x * y).sum(1))

        n_old = np.cross(Pv - Pu, Pc - Pu) + np.cross(Pu - Pv, Pd - Pv)
        n1 = np.cross(Pd - Pu, Pc - Pu)
        n2 = np.cross(Pv - Pd, Pc - Pd)
        ok = (ang(Pc, Pu, Pv) + ang(Pd, Pu, Pv) > np.pi + 1e-9) & ((n1 * n_old).sum(1) > 0) & ((n2 * n_old).sum(1) > 0)
        ok &= (C[:, 2] != C[:, 3]) & ~has_edge(mesh_keys, C[:, 2], C[:, 3])
        touched = set()
        flipped = 0
        for u, v, c, d, f1, f2 in C[ok].tolist():
            if f1 in touched or f2 in touched or (min(c, d), max(c, d)) in em:
                continue
            faces[f1] = [u, d, c]
            faces[f2] = [d, v, c]
            del em[(min(u, v), max(u, v))]
            em[(min(c, d), max(c, d))] = [f1, f2]
            for (x, y), old, new in (((u, d), f2, f1), ((v, c), f1, f2)):
                lst = em[(min(x, y), max(x, y))]
                lst[lst.index(old)] = new
            touched.update((f1, f2))
            flipped += 1
        return flipped

    for _ in range(max_rounds):
        em = edge_map()
        inner = np.asarray([k for k, fs in em.items() if len(fs) == 2], np.int64).reshape(-1, 2)
        P = points()
        ln = np.linalg.norm(P[inner[:, 0]] - P[inner[:, 1]], axis=1)
        sel = np.flatnonzero(ln > 4.0 / 3.0 * target)
        if len(sel) == 0:
            break
        sel = sel[np.argsort(-ln[sel], kind="stable")]
        long_edges = [(0.0, int(u), int(v)) for u, v in inner[sel]]
        touched = set()
        for _, u, v in long_edges:
            f1, f2 = em[(min(u, v), max(u, v))]
            if f1 in touched or f2 in touched:
                continue
            if not directed(f1, u, v):
                f1, f2 = f2, f1
            c, d = opposite(f1, u, v), opposite(f2, u, v)
            m = len(V)
            V.append(0.5 * (np.asarray(V[u]) + np.asarray(V[v])))
            faces[f1] = [u, m, c]
            faces.append([m, v, c])
            faces[f2] = [v, m, d]
            faces.append([m, u, d])
            touched.update((f1, f2, len(faces) - 1, len(faces) - 2))
        em = edge_map()
        for _ in range(3):
            if flip_pass(em) == 0:
                break
    em = edge_map()
    for _ in range(5):
        if flip_pass(em) == 0:
            break
    return V, faces


def uniform_laplacian(F: np.ndarray, n: int) -> sp.csr_matrix:
    """Umbrella operator ``L = I - D^-1 A`` over the edge graph of ``F`` (rows sum to 0)."""
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    A.data[:] = 1.0  # each undirected edge once
    deg = np.asarray(A.sum(1)).ravel()
    Dinv = sp.diags(np.divide(1.0, deg, out=np.zeros(n), where=deg > 0))
    return (sp.identity(n, format="csr") - Dinv @ A).tocsr()


def fair(V: np.ndarray, F: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Move ``free`` vertices so that ``L^2 x = 0`` there (bi-Laplacian fairing), others fixed."""
    free = np.asarray(free, np.int64)
    if len(free) == 0:
        return V
    n = len(V)
    L = uniform_laplacian(F, n)
    L2 = (L[free, :] @ L).tocsc()
    is_free = np.zeros(n, bool)
    is_free[free] = True
    fixed = np.flatnonzero(~is_free)
    A = L2[:, free]
    B = L2[:, fixed]
    rhs = -(B @ V[fixed])
    lu = spla.splu(A.tocsc())
    X = lu.solve(rhs)
    out = V.copy()
    out[free] = X
    return out


def _loop_edge_normals(V: np.ndarray, F: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Unit normal of the mesh face on each boundary edge ``loop[i] -> loop[i+1]``."""
    from ..mesh.core import face_normals

    src = F.ravel()
    dst = F[:, [1, 2, 0]].ravel()
    key = src * EDGE_KEY + dst
    order = np.argsort(key)
    want = loop * EDGE_KEY + np.roll(loop, -1)
    pos = np.clip(np.searchsorted(key[order], want), 0, len(order) - 1)
    hit = key[order][pos] == want
    N = np.zeros((len(loop), 3))
    N[hit] = face_normals(V, F)[order[pos[hit]] // 3]
    return N


def fill_loops(V, F, loops: list[np.ndarray], *, refine: bool = True, fairing: bool = True) -> StepResult:
    """Fill the given boundary loops with refined, faired patches.

    Returns a :class:`StepResult` whose ``changes`` hold one entry per filled loop
    (boundary edges, length, vertices and area added).
    """
    V, F = check_mesh(V, F)
    n0, m0 = len(V), len(F)
    Vl = [v for v in V]
    new_faces: list = []
    changes = []
    free: list = []
    for loop in loops:
        loop = np.asarray(loop, np.int64)
        if len(loop) < 3:
            raise MeshTopologyError(f"boundary loop with {len(loop)} edges cannot be filled (mesh not cleaned?)")
        before = len(Vl)
        Vcur = np.asarray(Vl, np.float64).reshape(-1, 3)
        keys = edge_keys(np.concatenate([F, np.asarray(new_faces, np.int64).reshape(-1, 3)]))
        tris, pts = triangulate_loop(Vcur, loop, keys, edge_normals=_loop_edge_normals(V, F, loop))
        tris = tris.tolist()
        Vl.extend(pts)
        if refine and len(tris) > 1:
            P = V[loop]
            target = float(np.linalg.norm(P - np.roll(P, -1, 0), axis=1).mean())
            Vl, tris = refine_patch(Vl, tris, target, keys)
        free.extend(range(before, len(Vl)))
        new_faces.extend(tris)
        changes.append(
            {
                "step": "fill_hole",
                "boundary_edges": int(len(loop)),
                "boundary_length": loop_length(V, loop),
                "vertices_added": int(len(Vl) - before),
                "faces_added": len(tris),
            }
        )
    V2 = np.asarray(Vl, np.float64).reshape(-1, 3)
    F2 = np.concatenate([F, np.asarray(new_faces, np.int64).reshape(-1, 3)])
    if fairing and free:
        V2 = fair(V2, F2, np.asarray(free))
    # area added per patch, after fairing
    from ..mesh.core import face_areas

    A = face_areas(V2, F2[m0:])
    start = 0
    for ch in changes:
        ch["area_added"] = float(A[start : start + ch["faces_added"]].sum())
        start += ch["faces_added"]
    vmap = np.concatenate([np.arange(n0), -np.ones(len(V2) - n0, np.int64)])
    fmap = np.concatenate([np.arange(m0), -np.ones(len(F2) - m0, np.int64)])
    return StepResult(V2, F2, vmap.astype(np.int64), fmap.astype(np.int64), changes)


def fill_holes(V, F, *, keep: Keep | int = "longest", refine: bool = True, fairing: bool = True) -> StepResult:
    """Fill every boundary loop except the one kept as the disk boundary.

    Parameters
    ----------
    keep : "longest" | "none" | int
        ``"longest"`` keeps the geometrically longest loop open, ``"none"`` fills all,
        an integer keeps the loop through that vertex index.
    refine, fairing : bool
        Refine patches to the surrounding edge length; fair them (bi-Laplacian).
    """
    V, F = check_mesh(V, F)
    loops = boundary_loops(F)
    if not loops:
        return StepResult.identity(V, F)
    if isinstance(keep, str):
        if keep not in ("longest", "none"):
            raise InvalidMeshError(f"keep must be 'longest', 'none' or a vertex index; got {keep!r}")
        kept = int(np.argmax([loop_length(V, lp) for lp in loops])) if keep == "longest" else -1
    else:
        hits = [i for i, lp in enumerate(loops) if int(keep) in set(lp.tolist())]
        if not hits:
            raise InvalidMeshError(f"vertex {keep} is not on a boundary loop")
        kept = hits[0]
    todo = [lp for i, lp in enumerate(loops) if i != kept]
    if not todo:
        return StepResult.identity(V, F)
    return fill_loops(V, F, todo, refine=refine, fairing=fairing)
