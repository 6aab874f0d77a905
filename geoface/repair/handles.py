"""Handle removal: cut along short non-separating loops and cap both sides until genus 0.

Loops come from a tree-cotree decomposition (Eppstein 2003) built on a shortest-path
tree, with the dual spanning tree maximising loop length, so the leftover edges give the
greedy shortest system of loops through the root (Erickson & Whittlesey 2005).  Each
loop is trimmed to start at the lowest common ancestor of its ends (the shared tail is
traversed twice and is homologically trivial), which leaves a simple cycle in the same
non-trivial homology class, hence non-separating.  Cutting it and capping both sides
lowers the genus by exactly one.

Examples
--------
>>> from geoface.synth import torus
>>> V, F = torus(1.0, 0.3, 32, 12)
>>> res = remove_handles(V, F)
>>> [c["step"] for c in res.changes][:1]
['cut_handle']
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree

from ..errors import MeshTopologyError
from ..mesh.core import boundary_loops, check_mesh, edge_topology, manifold_halfedge_pairs
from .clean import split_vertices_by_fans
from .holes import fill_loops
from .step import StepResult


def _genus_closed(V: np.ndarray, F: np.ndarray) -> int:
    et = edge_topology(F)
    used = len(np.unique(F))
    chi = used - len(et.E) + len(F)
    return (2 - chi) // 2


def _tree_path(pred: np.ndarray, v: int) -> list[int]:
    path = [v]
    while pred[path[-1]] >= 0:
        path.append(int(pred[path[-1]]))
    return path


def shortest_nontrivial_loop(V: np.ndarray, F: np.ndarray, roots: list[int], avoid: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """A short non-separating cycle (vertex loop) on a closed, oriented manifold of genus > 0.

    Tries each root and returns the shortest loop found and its length.  Vertices in
    ``avoid`` (e.g. a temporary cap) get prohibitively long edges.
    """
    n, m = len(V), len(F)
    et = edge_topology(F)
    E = et.E
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    if avoid is not None and len(avoid):
        bad = np.isin(E, avoid).any(1)
        w = np.where(bad, w + 1e6 * (w.sum() + 1.0), w)
    w = np.maximum(w, 1e-300)
    G = sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])), shape=(n, n)).tocsr()
    pairs = manifold_halfedge_pairs(et)
    pair_edge = et.he_edge[pairs[:, 0]]
    f1, f2 = pairs[:, 0] // 3, pairs[:, 1] // 3
    best = (None, np.inf)
    for root in roots:
        dist, pred = dijkstra(G, directed=False, indices=root, return_predecessors=True)
        pred = np.where(pred < 0, -1, pred)
        # primal tree edges: (v, pred[v])
        tv = np.flatnonzero(pred >= 0)
        tkey = np.minimum(tv, pred[tv]) * n + np.maximum(tv, pred[tv])
        ekey = E[:, 0] * n + E[:, 1]
        in_tree = np.isin(ekey, tkey)
        loop_len = dist[E[:, 0]] + dist[E[:, 1]] + w
        # dual graph over faces, edges not in the primal tree, maximum spanning tree
        nt = ~in_tree[pair_edge] & np.isfinite(loop_len[pair_edge])  # the root's component only
        if not nt.any():
            continue
        dw = loop_len[pair_edge[nt]]
        dual_w = (dw.max() + 1.0) - dw  # positive; minimising it maximises loop length
        D = sp.coo_matrix((dual_w, (f1[nt], f2[nt])), shape=(m, m)).tocsr()
        T = minimum_spanning_tree(D).tocoo()
        # int64 keys: SciPy's int32 rows and columns overflow ``row * m`` above 46,340 faces,
        # which marked the wrong cotree and gave loops around single faces
        tr, tc = T.row.astype(np.int64), T.col.astype(np.int64)
        dkey = np.minimum(tr, tc) * m + np.maximum(tr, tc)
        pkey = np.minimum(f1, f2) * m + np.maximum(f1, f2)
        in_cotree = np.zeros(len(E), bool)
        # an edge is in the cotree if its pair of faces was linked by the dual MST
        hit = np.isin(pkey, dkey) & nt
        in_cotree[pair_edge[hit]] = True
        left = np.flatnonzero(~in_tree & ~in_cotree)
        if len(left) == 0:
            continue
        for e in left[np.argsort(loop_len[left])][:8]:
            u, v = int(E[e, 0]), int(E[e, 1])
            pu, pv = _tree_path(pred, u), _tree_path(pred, v)
            # trim the common tail (towards the root) down to the lowest common ancestor
            while len(pu) > 1 and len(pv) > 1 and pu[-2] == pv[-2]:
                pu.pop()
                pv.pop()
            if pu[-1] != pv[-1]:
                continue
            cyc = pu[:-1] + [pu[-1]] + pv[:-1][::-1]
            cyc = np.asarray(cyc, np.int64)
            if len(np.unique(cyc)) != len(cyc) or len(cyc) < 3:
                continue
            L = float(np.linalg.norm(V[cyc] - V[np.roll(cyc, -1)], axis=1).sum())
            if L < best[1]:
                best = (cyc, L)
            break
    if best[0] is None:
        raise MeshTopologyError("could not find a non-separating loop (mesh not a closed orientable manifold?)")
    return best


def cut_along_loop(V: np.ndarray, F: np.ndarray, loop: np.ndarray, separate: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut the surface open along a closed edge loop: its vertices are duplicated per side."""
    et = edge_topology(F)
    n = len(V)
    a, b = loop, np.roll(loop, -1)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    ekey = et.E[:, 0] * n + et.E[:, 1]
    cut = np.isin(ekey, key)
    pairs = manifold_halfedge_pairs(et)
    pairs = pairs[~cut[et.he_edge[pairs[:, 0]]]]
    # move the two sides apart (a quarter of the way to their fans' centres) so the caps
    # that close them do not coincide
    return split_vertices_by_fans(V, F, pairs, separate=separate)


def remove_handles(V, F, *, max_handles: int = 100, n_roots: int = 3, seed: int = 0) -> StepResult:
    """Bring a manifold, oriented mesh with at most one boundary loop to genus 0.

    A surface with one boundary loop is temporarily closed with a cone over that loop
    (loops avoid it); the cone is removed at the end, restoring the boundary.

    Raises
    ------
    MeshTopologyError
        More than one boundary loop, or more than ``max_handles`` handles.
    """
    V, F = check_mesh(V, F)
    n0, m0 = len(V), len(F)
    loops = boundary_loops(F)
    if len(loops) > 1:
        raise MeshTopologyError(f"remove_handles needs at most one boundary loop; got {len(loops)} (fill holes first)")
    cone_faces = np.zeros((0, 3), np.int64)
    Vw, Fw = V, F
    apex = None
    if loops:
        lp = loops[0]
        apex = len(V)
        Vw = np.concatenate([V, V[lp].mean(0, keepdims=True)])
        cone_faces = np.stack([np.roll(lp, -1), lp, np.full(len(lp), apex)], 1)
        Fw = np.concatenate([F, cone_faces])
    genus = _genus_closed(Vw, Fw)
    if genus == 0:
        return StepResult.identity(V, F)
    if genus > max_handles:
        raise MeshTopologyError(f"mesh has genus {genus} > max_handles={max_handles}; clean or remesh it first")
    rng = np.random.default_rng(seed)
    # vertex / face provenance through the cuts (cone faces tracked as -2)
    vmap = np.arange(len(Vw), dtype=np.int64)
    fmap = np.concatenate([np.arange(m0), np.full(len(cone_faces), -2)]).astype(np.int64)
    changes = []
    avoid = np.array([apex]) if apex is not None else None
    for _ in range(genus):
        used = np.unique(Fw)
        roots = [int(used[0])] + [int(x) for x in rng.choice(used, size=min(n_roots - 1, len(used)), replace=False)]
        if apex is not None:
            roots = [r for r in roots if r != apex] or [int(used[0])]
        loop, length = shortest_nontrivial_loop(Vw, Fw, roots, avoid)
        V2, F2, vm = cut_along_loop(Vw, Fw, loop)
        new_loops = [lp for lp in boundary_loops(F2)]
        filled = fill_loops(V2, F2, new_loops)
        vmap = np.concatenate([vmap[vm], -np.ones(len(filled.V) - len(V2), np.int64)])
        fmap = np.concatenate([fmap, -np.ones(len(filled.F) - len(F2), np.int64)])
        area = sum(c["area_added"] for c in filled.changes)
        changes.append({"step": "cut_handle", "loop_edges": int(len(loop)), "loop_length": length, "area_added": float(area)})
        Vw, Fw = filled.V, filled.F
        if _genus_closed(Vw, Fw) == 0:
            break
    g = _genus_closed(Vw, Fw)
    if g != 0:
        raise MeshTopologyError(f"handle removal left genus {g}")
    if apex is not None:
        keep = fmap != -2
        Fw = Fw[keep]
        fmap = fmap[keep]
        apex_now = np.flatnonzero(vmap == apex)
        if len(apex_now):
            used = np.ones(len(Vw), bool)
            used[apex_now] = False
            idx = np.flatnonzero(used)
            remap = -np.ones(len(Vw), np.int64)
            remap[idx] = np.arange(len(idx))
            Vw, Fw, vmap = Vw[idx], remap[Fw], vmap[idx]
    vmap = np.where(vmap >= n0, -1, vmap)
    return StepResult(Vw, Fw, vmap, fmap, changes)
