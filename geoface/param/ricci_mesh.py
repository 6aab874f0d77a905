"""Combinatorial repairs of the mesh around a Ricci flow (:mod:`geoface.param.ricci`): ears
flipped before it, boundary edges flattened by it found for splitting, degenerate triangles
counted."""

from __future__ import annotations

import numpy as np

from ..mesh.core import edge_keys, halfedge_twins, has_edge
from .delaunay import IntrinsicTriangulation
from .intrinsic import corner_angles


def flip_ears(V: np.ndarray, F: np.ndarray, boundary: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip the edge opposite every boundary vertex that has a single triangle.

    Such a vertex can never reach a straight boundary angle (pi) without its triangle
    degenerating, so Newton would crawl along the energy's degenerate extension.  The
    flip gives it two triangles; it is skipped where it would duplicate an edge or fold
    the surface (new normals against the old ones).
    """
    F = F.copy()
    count = np.bincount(F.ravel(), minlength=len(V))
    ears = boundary[count[boundary] == 1]
    if len(ears) == 0:
        return F, 0
    keys = edge_keys(F)
    twin = halfedge_twins(F)
    done = 0
    touched = set()
    for v in ears.tolist():
        f = int(np.flatnonzero((F == v).any(1))[0])
        k = int(np.flatnonzero(F[f] == v)[0])
        b, c = int(F[f, (k + 1) % 3]), int(F[f, (k + 2) % 3])
        h = int(twin[3 * f + (k + 1) % 3])  # twin of half-edge b -> c
        if h < 0 or f in touched:
            continue
        g = h // 3
        if g in touched:
            continue
        d = int(F[g, (h % 3 + 2) % 3])
        # (a flip can never re-create another flip's new edge: both faces of each
        # flip are marked touched, and every ear has only one face)
        if d == v or has_edge(keys, v, d):
            continue
        new1, new2 = (v, b, d), (v, d, c)
        n_old = np.cross(V[b] - V[v], V[c] - V[v]) + np.cross(V[b] - V[c], V[d] - V[c])
        if any(np.cross(V[t[1]] - V[t[0]], V[t[2]] - V[t[0]]) @ n_old <= 0 for t in (new1, new2)):
            continue
        F[f], F[g] = new1, new2
        touched.update((f, g))
        done += 1
    return F, done


def degenerate_boundary_edges(tri: IntrinsicTriangulation, u: np.ndarray, tol: float = 1e-4) -> list[tuple[int, int]]:
    """Boundary edges ``(a, b)`` whose opposite angle is within ``tol`` of pi (or whose
    triangle breaks the triangle inequality) in the metric scaled by ``u``."""
    lc = tri.corner_lengths(u)
    ang = corner_angles(lc)
    a, b, c = lc[:, 0], lc[:, 1], lc[:, 2]
    bad = ~((a < b + c) & (b < c + a) & (c < a + b)) | (ang.max(1) > np.pi - tol)
    out = []
    for f in np.flatnonzero(bad).tolist():
        k = int(np.argmax(ang[f]))
        h = 3 * f + (k + 1) % 3  # the half-edge opposite corner k
        if tri.twin[h] < 0:
            out.append((int(tri.F[f, (k + 1) % 3]), int(tri.F[f, (k + 2) % 3])))
    return out


def n_degenerate(ang: np.ndarray) -> int:
    """Triangles at the triangle-inequality limit (an angle of 0 or pi)."""
    return int(((ang < 1e-12) | (ang > np.pi - 1e-12)).any(1).sum())


def refine_boundary_band(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One round of red-green refinement of the triangles along the boundary: every triangle
    with a boundary edge, and every triangle that would otherwise have two or three split edges,
    is split in four at its edges' midpoints (red); a triangle with one split edge is halved
    from its midpoint (green). The boundary doubles its vertices, the surface keeps its shape
    (midpoints of straight edges), and the triangles stay well shaped (red ones are similar to
    their parent, green ones halves), unlike a fan of midpoint splits at one vertex.

    Returns ``(V, F, edges)``: the new vertices appended in the order of ``edges (k, 2)``, each
    the midpoint of its edge ``(a, b)`` (the convention of ``RicciFlowSolver.split_edges``)."""
    from ..mesh.core import boundary_loops

    F = np.asarray(F, np.int64)
    E = np.sort(np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], 1), axis=2)  # (m, 3, 2): edge k = (F[k], F[k+1])
    keys = E[:, :, 0] * (len(V) + 1) + E[:, :, 1]
    uniq, inv = np.unique(keys.ravel(), return_inverse=True)
    inv = inv.reshape(-1, 3)
    bnd = np.zeros(len(uniq), bool)
    for loop in boundary_loops(F):
        a, b = np.minimum(loop, np.roll(loop, -1)), np.maximum(loop, np.roll(loop, -1))
        bnd[np.searchsorted(uniq, a * (len(V) + 1) + b)] = True
    red = bnd[inv].any(1)
    split = np.zeros(len(uniq), bool)
    while True:
        split[inv[red].ravel()] = True
        more = ~red & (split[inv].sum(1) >= 2)
        if not more.any():
            break
        red |= more
    ids = np.flatnonzero(split)
    mid = np.full(len(uniq), -1, np.int64)
    mid[ids] = len(V) + np.arange(len(ids))
    edges = np.stack([uniq[ids] // (len(V) + 1), uniq[ids] % (len(V) + 1)], 1)
    V2 = np.vstack([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])])
    m = mid[inv]  # (m, 3): midpoint of edge k of each face, -1 where not split
    out = [F[(m < 0).all(1)]]
    r = red
    a, b, c = F[r, 0], F[r, 1], F[r, 2]
    mab, mbc, mca = m[r, 0], m[r, 1], m[r, 2]
    out += [np.stack(t, 1) for t in ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))]
    g = ~red & ((m >= 0).sum(1) == 1)
    for k in range(3):  # green: the one split edge is edge k = (F[k], F[k+1]); the apex is F[k+2]
        s = g & (m[:, k] >= 0)
        p, q, x, mm = F[s, k], F[s, (k + 1) % 3], F[s, (k + 2) % 3], m[s, k]
        out += [np.stack([p, mm, x], 1), np.stack([mm, q, x], 1)]
    return V2, np.concatenate(out).astype(np.int64), edges
