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
