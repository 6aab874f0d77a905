"""Orientation of faces linked across manifold edges (vectorised, no loop over faces)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components

from .core import accumulate_to_root


@dataclass(frozen=True)
class OrientationSolution:
    """Which faces to flip so linked faces agree.

    Attributes
    ----------
    flip : (m,) bool, faces to reverse
    inconsistent : (p,) bool, pairs still disagreeing after the flips (non-orientable part)
    same_direction : (p,) bool, pairs that disagree *before* flipping
    face_component : (m,) int64, component of each face in the linked-face graph
    """

    flip: np.ndarray
    inconsistent: np.ndarray
    same_direction: np.ndarray
    face_component: np.ndarray


def solve_orientation(F: np.ndarray, pairs: np.ndarray) -> OrientationSolution:
    """Find face flips making every linked pair traverse its edge in opposite directions.

    Two faces on a shared edge are consistently oriented when they use it in opposite
    directions.  A spanning forest of the linked-face graph fixes each face's flip
    relative to its root (parities accumulated by pointer jumping); pairs off the tree
    that still disagree witness a non-orientable component (e.g. a Moebius strip).
    Within each component the orientation most faces already have is kept.
    """
    m = len(F)
    src = F.ravel()
    h1, h2 = pairs[:, 0], pairs[:, 1]
    same = src[h1] == src[h2] if len(pairs) else np.zeros(0, bool)
    f1, f2 = h1 // 3, h2 // 3
    ncomp, comp = connected_components(
        sp.coo_matrix((np.ones(len(f1), np.int8), (f1, f2)), shape=(m, m)), directed=False
    )
    # one BFS from a virtual super-root (node m) joined to the first face of every component
    roots = np.unique(comp, return_index=True)[1]
    rows = np.concatenate([f1, np.full(len(roots), m)])
    cols = np.concatenate([f2, roots])
    G = sp.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(m + 1, m + 1)).tocsr()
    _, pred = breadth_first_order(G, m, directed=False, return_predecessors=True)
    parent = pred[:m].astype(np.int64)
    parent[roots] = roots
    # parity of each tree edge (face, parent): look the pair up by an undirected key
    key = np.minimum(f1, f2) * m + np.maximum(f1, f2)
    order = np.argsort(key, kind="stable")
    skey = key[order]
    tree_key = np.minimum(np.arange(m), parent) * m + np.maximum(np.arange(m), parent)
    pos = np.clip(np.searchsorted(skey, tree_key), 0, max(len(skey) - 1, 0))
    acc = np.zeros(m, bool)
    nonroot = parent != np.arange(m)
    if len(skey):
        acc[nonroot] = same[order[pos[nonroot]]]
    flip = accumulate_to_root(parent, acc, np.bitwise_xor)
    # keep the majority orientation of each component
    frac = np.bincount(comp, weights=flip.astype(float), minlength=ncomp) / np.maximum(np.bincount(comp, minlength=ncomp), 1)
    flip = flip ^ (frac > 0.5)[comp]
    inconsistent = (flip[f1] ^ flip[f2]) != same
    return OrientationSolution(flip, inconsistent, same, comp.astype(np.int64))
