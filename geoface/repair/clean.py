"""Cleaning: merge duplicate vertices, remove degenerate/duplicate faces, split non-manifold
vertices and edges, make orientation consistent, drop unreferenced vertices.

Each function takes ``(V, F)`` and returns a :class:`~geoface.repair.step.StepResult`.

>>> from geoface.synth import square_grid
>>> V, F = square_grid(5)
>>> clean(V, F).changes
[]
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..mesh.core import (
    bbox_diagonal,
    check_mesh,
    double_sided_faces,
    duplicate_faces,
    edge_keys,
    edge_topology,
    has_edge,
    face_areas,
    vertex_fans,
)
from ..mesh.orient import solve_orientation
from ..tol import tol
from .step import StepResult, select_faces


def merge_vertices(V, F, tolerance: float | None = None) -> StepResult:
    """Merge vertices closer than ``tolerance * bbox_diagonal`` (default ``tol.merge``).

    Clusters are transitive (union of close pairs); each keeps its lowest-index vertex.
    Faces are re-indexed; vertices that became unused are removed.
    """
    V, F = check_mesh(V, F)
    rel = tol.merge if tolerance is None else float(tolerance)
    r = rel * bbox_diagonal(V)
    pairs = cKDTree(V).query_pairs(r, output_type="ndarray") if r > 0 else np.zeros((0, 2), np.int64)
    if len(pairs) == 0:
        return StepResult.identity(V, F)
    n = len(V)
    G = sp.coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(G, directed=False)
    rep = np.full(lab.max() + 1, n)
    np.minimum.at(rep, lab, np.arange(n))
    target = rep[lab]
    merged = int((target != np.arange(n)).sum())
    F2 = target[F]
    res = select_faces(V, F2, np.ones(len(F2), bool), [{"step": "merge_vertices", "merged": merged, "distance": r}])
    return res


def _degenerate_mask(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Faces with a repeated index, or zero area relative to the bbox or to their own edges."""
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    A = face_areas(V, F)
    e = V[F[:, [1, 2, 0]]] - V[F]
    lmax2 = (e**2).sum(-1).max(1)
    diag = bbox_diagonal(V)
    return rep | (A <= np.maximum(tol.area_eps * diag * diag, tol.cap_eps * lmax2))


#: double-sided faces (a triangle and its reverse) up to this share of all faces are fins, removed
FIN_SHARE = 0.1


def remove_degenerate_faces(V, F, max_rounds: int = 8) -> StepResult:
    """Remove faces with repeated indices and duplicate faces; repair zero-area "caps".

    A cap is a triangle whose apex lies on its longest edge (area 0, no short edge).
    Deleting it would punch a slit into the surface, so the longest edge is flipped
    with the neighbouring face instead (both new triangles have positive area).  A cap
    on the boundary, or whose flip is impossible, is deleted (its area is zero, so the
    surface does not change).
    """
    V, F = check_mesh(V, F)
    F = F.copy()
    changes = []
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    dup = duplicate_faces(F) & ~rep
    # a triangle together with its reverse is a sheet of no thickness: on a few faces a fin
    # hanging off the surface (removed, both sides); on many, a double-sided export (one kept)
    fin = double_sided_faces(F) & ~rep
    if fin.any():
        # a fin hangs off the surface: one of its corners belongs to no face outside the sheet;
        # a reversed copy of a face inside the surface (all corners shared) is only a duplicate
        others = np.bincount(F[~fin & ~rep].ravel(), minlength=len(V))
        fin &= (others[F] == 0).any(1)
    if fin.any() and fin.sum() <= FIN_SHARE * len(F):
        dup &= ~fin
        changes.append({"step": "remove_fins", "removed": int(fin.sum())})
    else:
        fin[:] = False
    keep = ~(rep | dup | fin)
    if rep.any():
        changes.append({"step": "remove_degenerate_faces", "repeated_index": int(rep.sum())})
    if dup.any():
        changes.append({"step": "remove_duplicate_faces", "removed": int(dup.sum())})
    res = select_faces(V, F, keep)
    V, F = res.V, res.F.copy()
    face_map = res.face_map.copy()
    flips = deleted = 0
    alive = np.ones(len(F), bool)
    for _ in range(max_rounds):
        deg = np.flatnonzero(_degenerate_mask(V, F) & alive)
        if len(deg) == 0:
            break
        et = edge_topology(F)
        keys = edge_keys(F)
        he_order = np.argsort(et.he_edge, kind="stable")
        he_sorted = et.he_edge[he_order]
        touched = np.zeros(len(F), bool)
        for f in deg:
            if touched[f]:
                continue
            P = V[F[f]]
            k = int(np.argmax(np.linalg.norm(P[[1, 2, 0]] - P, axis=1)))  # edge k: F[f,k] -> F[f,k+1]
            a, b, c = int(F[f, k]), int(F[f, (k + 1) % 3]), int(F[f, (k + 2) % 3])
            e = et.he_edge[3 * f + k]
            hs = he_order[np.searchsorted(he_sorted, e, "left"):np.searchsorted(he_sorted, e, "right")]
            others = [int(h) for h in hs if h // 3 != f and alive[h // 3]]
            ok = len(others) == 1
            if ok:
                h = others[0]
                g = h // 3
                d = int(F[g, (h % 3 + 2) % 3])
                ok = not touched[g] and et.he_src[h] == b and et.he_dst[h] == a and c != d and not has_edge(keys, c, d)
            if ok:
                F[f] = (a, d, c)  # flip the longest edge a-b to c-d
                F[g] = (d, b, c)
                touched[[f, g]] = True
                flips += 1
            else:
                alive[f] = False
                touched[f] = True
                deleted += 1
    leftover = _degenerate_mask(V, F) & alive
    if leftover.any():
        alive &= ~leftover
        deleted += int(leftover.sum())
    if flips or deleted:
        changes.append({"step": "repair_caps", "flipped": flips, "deleted": deleted})
    res2 = select_faces(V, F, alive)
    return StepResult(res2.V, res2.F, res.vertex_map[res2.vertex_map], face_map[res2.face_map], changes)


def _choose_pairs(V: np.ndarray, F: np.ndarray, et) -> tuple[np.ndarray, np.ndarray]:
    """Link faces across edges: every 2-face edge as it is; the faces around an edge with
    more than two are paired greedily into the smoothest continuations.

    Pair score: the cosine between the two normals, as seen with consistent orientation
    (faces using the edge in the same direction have one normal flipped), with a small
    preference for pairs that are already consistent.  A fin on a plane thus leaves the
    plane joined; two crossing sheets each stay whole.

    Returns ``(pairs, primary)``: ``primary[i]`` marks the best pair of each >2-face edge.
    """
    order = np.argsort(et.he_edge, kind="stable")
    e_sorted = et.he_edge[order]
    cnt = et.edge_faces[e_sorted]
    two = order[cnt == 2].reshape(-1, 2)
    nm = order[cnt > 2]
    extra, primary = [], []
    if len(nm):
        from ..mesh.core import face_normals

        N = face_normals(V, F)
        starts = np.flatnonzero(np.r_[True, et.he_edge[nm][1:] != et.he_edge[nm][:-1]])
        for hs in np.split(nm, starts[1:]):
            fs = hs // 3
            sgn = np.where(et.he_src[hs] == et.he_src[hs[0]], 1.0, -1.0)
            cos = N[fs] @ N[fs].T
            consistent = sgn[:, None] != sgn[None, :]
            score = np.where(consistent, cos + 1e-3, -cos)
            np.fill_diagonal(score, -np.inf)
            left = np.ones(len(hs), bool)
            first = True
            while left.sum() >= 2:
                sc = np.where(left[:, None] & left[None, :], score, -np.inf)
                i, j = np.unravel_index(np.argmax(sc), sc.shape)
                extra.append((hs[i], hs[j]))
                primary.append(first)
                first = False
                left[[i, j]] = False
    pairs = np.concatenate([two, np.asarray(extra, np.int64).reshape(-1, 2)])
    prim = np.concatenate([np.zeros(len(two), bool), np.asarray(primary, bool)])
    return pairs.astype(np.int64), prim


def split_vertices_by_fans(V: np.ndarray, F: np.ndarray, pairs: np.ndarray, separate: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Give each fan of faces around a vertex its own vertex copy.

    Returns ``(V2, F2, vertex_map)``: the first fan of vertex ``v`` keeps index ``v``,
    further fans get new indices appended at the end.  With ``separate > 0`` every copy
    of a split vertex moves that fraction of the way towards the centre of its own fan,
    so the copies no longer coincide.
    """
    n = len(V)
    nf, lab = vertex_fans(F, pairs)
    corner_v = F.ravel()
    fan_v = np.zeros(nf, np.int64)
    fan_v[lab] = corner_v
    # first fan (lowest fan id) of each vertex keeps the vertex's index
    first_fan = np.full(n, nf, np.int64)
    np.minimum.at(first_fan, fan_v, np.arange(nf))
    is_first = first_fan[fan_v] == np.arange(nf)
    new_index = np.empty(nf, np.int64)
    new_index[is_first] = fan_v[is_first]
    extra = np.flatnonzero(~is_first)
    new_index[extra] = n + np.arange(len(extra))
    F2 = new_index[lab].reshape(-1, 3)
    vmap = np.concatenate([np.arange(n), fan_v[extra]]).astype(np.int64)
    V2 = V[vmap]
    if separate > 0 and len(extra):
        split = np.zeros(n, bool)
        split[fan_v[extra]] = True
        # centre of each fan: mean of the midpoints of the corners' opposite edges
        opp = 0.5 * (V[F[:, [1, 2, 0]]] + V[F[:, [2, 0, 1]]]).reshape(-1, 3)
        cnt = np.bincount(lab, minlength=nf)
        centre = np.stack([np.bincount(lab, weights=opp[:, k], minlength=nf) for k in range(3)], 1) / np.maximum(cnt, 1)[:, None]
        moving = np.flatnonzero(split[fan_v])
        idx = new_index[moving]
        V2[idx] += separate * (centre[moving] - V2[idx])
    return V2, F2, vmap


def make_manifold(V, F, max_rounds: int = 4, separate: float = 0.01) -> StepResult:
    """Split non-manifold vertices and edges and orient all faces consistently.

    * The faces around an edge with more than two are paired into the smoothest
      continuations (see :func:`_choose_pairs`); every pair stays joined, so each sheet
      through the edge stays whole, and the vertex split below separates the sheets.
    * Faces are flipped so joined faces agree (the majority orientation of each
      component wins).  Where no flips can make a component agree (a non-orientable
      surface such as a Moebius strip), the disagreeing joins are cut.
    * Every vertex whose faces form several fans is split into one vertex per fan.

    Faces that still sit on an edge with more than two faces afterwards (only possible
    in pathological configurations) are removed and reported.

    Copies of a split vertex are moved apart by ``separate`` times the distance to their
    fan's centre (1% by default), so they are no longer duplicates: cleaning the result
    again changes nothing.
    """
    V, F = check_mesh(V, F)
    total = StepResult.identity(V, F)
    for rnd in range(max_rounds):
        V, F = total.V, total.F
        et = edge_topology(F)
        pairs, _ = _choose_pairs(V, F, et)
        sol = solve_orientation(F, pairs)
        changes = []
        nm_edges = int((et.edge_faces > 2).sum())
        if nm_edges:
            changes.append({"step": "split_nonmanifold_edges", "edges": nm_edges})
        if sol.inconsistent.any():
            changes.append({"step": "cut_nonorientable", "edges": int(sol.inconsistent.sum())})
            pairs = pairs[~sol.inconsistent]
        V2, F2, vmap = split_vertices_by_fans(V, F, pairs, separate=separate)
        if len(V2) > len(V):
            changes.append({"step": "split_nonmanifold_vertices", "copies_added": int(len(V2) - len(V))})
        nflip = int(sol.flip.sum())
        if nflip:
            F2 = np.where(sol.flip[:, None], F2[:, ::-1], F2)
            changes.append({"step": "orient_faces", "flipped": nflip})
        step = StepResult(V2, F2, vmap, np.arange(len(F2), dtype=np.int64), changes)
        total = total.then(step)
        et2 = edge_topology(F2)
        if not (et2.edge_faces > 2).any():
            break
        if rnd == max_rounds - 1:
            # last resort: on each remaining >2-face edge keep only its best pair
            kept_pairs, primary = _choose_pairs(V2, F2, et2)
            on_nm = np.isin(et2.he_edge, et2.nonmanifold_edges)
            in_pair = np.zeros(3 * len(F2), bool)
            in_pair[kept_pairs[primary | (et2.edge_faces[et2.he_edge[kept_pairs[:, 0]]] == 2)].ravel()] = True
            bad = (on_nm & ~in_pair).reshape(-1, 3).any(1)
            total = total.then(select_faces(V2, F2, ~bad, [{"step": "remove_nonmanifold_faces", "removed": int(bad.sum())}]))
    # removing faces can leave bow-tie vertices: split them (all edges are manifold now)
    from ..mesh.core import manifold_halfedge_pairs, nonmanifold_vertices

    if len(nonmanifold_vertices(total.F, len(total.V))):
        pairs = manifold_halfedge_pairs(edge_topology(total.F))
        V3, F3, vm3 = split_vertices_by_fans(total.V, total.F, pairs, separate=separate)
        total = total.then(StepResult(V3, F3, vm3, np.arange(len(F3), dtype=np.int64), [{"step": "split_nonmanifold_vertices", "copies_added": int(len(V3) - len(total.V))}]))
    # drop vertices that no face uses any more
    used = np.zeros(len(total.V), bool)
    used[total.F.ravel()] = True
    if not used.all():
        total = total.then(select_faces(total.V, total.F, np.ones(len(total.F), bool)))
    return total


def remove_unreferenced_vertices(V, F) -> StepResult:
    """Drop vertices no face uses."""
    V, F = check_mesh(V, F)
    res = select_faces(V, F, np.ones(len(F), bool))
    dropped = len(V) - len(res.V)
    if dropped:
        res = StepResult(res.V, res.F, res.vertex_map, res.face_map, [{"step": "remove_unreferenced", "removed": dropped}])
    return res


def clean(V, F, *, merge_tolerance: float | None = None) -> StepResult:
    """All cleaning steps in order: merge, degenerate/duplicate faces, manifold + orientation, unreferenced.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    merge_tolerance : float, optional
        Relative merge distance (times the bbox diagonal); default ``tol.merge``.

    Returns
    -------
    StepResult with maps back to the input and a list of the changes made.
    """
    V, F = check_mesh(V, F)
    res = remove_unreferenced_vertices(V, F)
    res = res.then(merge_vertices(res.V, res.F, merge_tolerance))
    res = res.then(remove_degenerate_faces(res.V, res.F))
    res = res.then(make_manifold(res.V, res.F))
    return res
