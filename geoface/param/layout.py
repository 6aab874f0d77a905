"""Embedding a flat metric in the plane: the breadth-first layout of triangles from their corner
angles, its alignment to the rectangle the corners span, and that rectangle's fit into the
unit square (:mod:`geoface.param.ricci`)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order

from ..errors import InvalidMeshError, ParameterizationError
from ..mesh.core import accumulate_to_root, halfedge_twins
from .intrinsic import corner_angles

__all__ = ["layout", "to_unit_square"]


def to_unit_square(uv: np.ndarray, width: float, height: float, fit: str = "stretch") -> np.ndarray:
    """Map a ``[0, width] x [0, height]`` layout into ``[0, 1]^2``.

    ``stretch``: each side to 1 (no longer conformal unless the aspect is 1; what the image
    step does); ``uniform``: scaled to fit, centred (conformal); ``rectangle``: scaled to
    height 1, ``[0, aspect] x [0, 1]`` (conformal, not inside the unit square when the
    aspect exceeds 1)."""
    if fit == "rectangle":
        return uv / height
    if fit == "stretch":
        return np.clip(uv / np.array([width, height]), 0.0, 1.0)
    if fit == "uniform":
        s = max(width, height)
        off = (np.array([s - width, s - height]) / 2) / s
        return np.clip(uv / s + off, 0.0, 1.0)
    raise InvalidMeshError(f"fit must be 'stretch', 'uniform' or 'rectangle'; got {fit!r}")


def _corner_offsets(ang: np.ndarray) -> np.ndarray:
    """``off[f, a, b]``: direction of edge corner a -> corner b of face f, relative to the
    direction of its edge corner 0 -> corner 1 (faces counter-clockwise)."""
    m = len(ang)
    off = np.zeros((m, 3, 3))
    a0, a1 = ang[:, 0], ang[:, 1]
    off[:, 0, 1] = 0.0
    off[:, 0, 2] = a0
    off[:, 1, 2] = np.pi - a1
    off[:, 1, 0] = np.pi
    off[:, 2, 0] = np.pi + a0
    off[:, 2, 1] = -a1
    return off


def layout(l: np.ndarray, F: np.ndarray, ang: np.ndarray | None = None, twin: np.ndarray | None = None) -> np.ndarray:
    """Unfold a flat metric (lengths ``l``, ``(m, 3)``) into the plane, counter-clockwise.

    Breadth-first over faces, one BFS level at a time (vectorised).  The absolute
    direction of every face's first edge is propagated through the corner angles, and
    each new vertex is placed from an already placed one along that direction, so
    rounding errors only add up along the tree instead of being amplified (unfolding
    from the positions of the shared edge is unstable on long chains).

    ``twin`` (3m,) gives face adjacency by half-edges (needed for intrinsic
    triangulations with multi-edges); by default it is derived from ``F``.
    """
    m = len(F)
    n = int(F.max()) + 1
    ang = corner_angles(l) if ang is None else ang
    twin = halfedge_twins(F) if twin is None else twin
    h = np.flatnonzero(twin >= 0)
    G = sp.coo_matrix((np.ones(len(h)), (h // 3, twin[h] // 3)), shape=(m, m)).tocsr()
    order, pred = breadth_first_order(G, 0, directed=False, return_predecessors=True)
    if len(order) != m:
        raise ParameterizationError("faces are not edge-connected; cannot lay out")
    # for each non-root face, one of its half-edges whose twin lies in the BFS parent
    hf, tf = h // 3, twin[h] // 3
    link = np.full(m, -1, np.int64)
    sel = pred[hf] == tf
    link[hf[sel]] = h[sel]
    parent = np.where(pred < 0, np.arange(m), pred).astype(np.int64)
    depth = accumulate_to_root(parent, (pred >= 0).astype(np.int64))  # BFS depth
    off = _corner_offsets(ang)
    psi = np.zeros(m)  # absolute direction of edge corner0 -> corner1 of each face
    uv = np.zeros((n, 2))
    placed = np.zeros(n, bool)
    a, b, c = F[0]
    uv[b] = [l[0, 2], 0.0]  # edge a-b is opposite corner 2
    uv[c] = l[0, 1] * np.array([np.cos(ang[0, 0]), np.sin(ang[0, 0])])
    placed[[a, b, c]] = True
    levels = np.argsort(depth, kind="stable")
    bounds = np.searchsorted(depth[levels], np.arange(1, int(depth.max()) + 2))
    for d in range(1, int(depth.max()) + 1):
        fs = levels[bounds[d - 1] : bounds[d]]
        hg = link[fs]
        mm = hg % 3  # the shared half-edge runs from corner mm to corner mm+1 of the child
        ht = twin[hg]
        pf, pp = ht // 3, ht % 3  # ... and from corner pp+1 to corner pp of the parent
        D = psi[pf] + off[pf, (pp + 1) % 3, pp]  # its direction, known from the parent
        psi[fs] = D - off[fs, mm, (mm + 1) % 3]
        k = (mm + 2) % 3  # the corner to place
        dir_mk = psi[fs] + off[fs, mm, k]
        lmk = l[fs, (mm + 1) % 3]  # edge corner mm - corner k is opposite corner mm+1
        i = F[fs, mm]
        newv = F[fs, k]
        todo = ~placed[newv]
        pos = uv[i] + lmk[:, None] * np.stack([np.cos(dir_mk), np.sin(dir_mk)], 1)
        uv[newv[todo]] = pos[todo]
        placed[newv[todo]] = True
    return uv


def align_rectangle(uv: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Translate corner 0 to the origin and rotate corner 1 onto +x."""
    p0, p1, p3 = uv[corners[0]], uv[corners[1]], uv[corners[3]]
    e = p1 - p0
    ang = np.arctan2(e[1], e[0])
    R = np.array([[np.cos(-ang), -np.sin(-ang)], [np.sin(-ang), np.cos(-ang)]])
    out = (uv - p0) @ R.T
    w = float(np.linalg.norm(e))
    h = float(np.linalg.norm(p3 - p0))
    return out, w, h
