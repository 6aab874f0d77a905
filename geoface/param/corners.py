"""Choosing the four rectangle corners on the boundary, and the paper's 8-fold augmentation.

>>> from geoface.synth import disk_grid
>>> V, F = disk_grid(6)
>>> len(corner_sets(V, F, n=8))
8
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterizationError
from ..mesh.core import boundary_loops, check_mesh


def boundary_arclength(V: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, float]:
    """Cumulative arc length at each loop vertex (starting at 0) and the total length."""
    seg = np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    return s, float(seg.sum())


def _reference(V: np.ndarray, loop: np.ndarray, reference: int | None, front) -> int:
    if reference is not None:
        r = int(reference)
        if r not in set(loop.tolist()):
            raise ParameterizationError(f"reference vertex {r} is not on the boundary")
        return r
    f = np.asarray((0.0, 0.0, 1.0) if front is None else front, np.float64)
    # the boundary vertex furthest along the front direction (for heads: under the chin)
    return int(loop[np.argmax(V[loop] @ f)])


def _split(V: np.ndarray, loop: np.ndarray, start: int, fractions: np.ndarray) -> np.ndarray:
    """Boundary vertices nearest to the given arc-length fractions, starting at ``start``."""
    k = int(np.flatnonzero(loop == start)[0])
    lp = np.roll(loop, -k)
    s, L = boundary_arclength(V, lp)
    idx = []
    for fr in fractions:
        target = fr * L
        d = np.abs(s - target)
        d = np.minimum(d, L - d)
        idx.append(int(np.argmin(d)))
    idx = np.array(idx)
    if len(np.unique(idx)) != len(idx):
        raise ParameterizationError("boundary too short to place distinct corners")
    return lp[idx]


def default_corners(V, F, reference: int | None = None, front=None) -> np.ndarray:
    """Four corners splitting the boundary into equal arc lengths from ``reference``.

    ``reference`` defaults to the boundary vertex furthest along ``front`` (default +Z,
    the face direction of an upright head: the boundary vertex under the chin).
    Returned counter-clockwise (in boundary order).
    """
    V, F = check_mesh(V, F)
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"need exactly one boundary loop; got {len(loops)}")
    loop = loops[0]
    return _split(V, loop, _reference(V, loop, reference, front), np.arange(4) / 4)


def corner_sets(V, F, n: int = 8, reference: int | None = None, front=None) -> list[np.ndarray]:
    """The paper's augmentation: the boundary split into ``n`` equal-length arcs; offset
    ``k`` puts the first corner at arc ``k`` and the others a quarter of the boundary apart.

    With ``n = 8`` this gives 8 ordered corner sets (two vertex sets, each in four
    rotations), hence 8 different parameterizations of one mesh.
    """
    V, F = check_mesh(V, F)
    if n < 1:
        raise ParameterizationError(f"n must be >= 1; got {n}")
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"need exactly one boundary loop; got {len(loops)}")
    loop = loops[0]
    start = _reference(V, loop, reference, front)
    return [_split(V, loop, start, (k / n + np.arange(4) / 4) % 1.0) for k in range(n)]
