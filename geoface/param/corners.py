"""Choosing the four rectangle corners on the boundary, and the paper's 8-fold augmentation.

The boundary is split by length into four equal arcs; the default set puts the boundary
point under the chin mid-way along the bottom side, and the eight augmentation sets turn
that split by 1/32 of the boundary each (eight different parameterizations).

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


def _reference(V: np.ndarray, loop: np.ndarray, reference: int | None, front, up) -> int:
    if reference is not None:
        r = int(reference)
        if r not in set(loop.tolist()):
            raise ParameterizationError(f"reference vertex {r} is not on the boundary")
        return r
    f = np.asarray((0.0, 0.0, 1.0) if front is None else front, np.float64)
    u = np.asarray((0.0, 1.0, 0.0) if up is None else up, np.float64)
    d = f / max(np.linalg.norm(f), 1e-300) - u / max(np.linalg.norm(u), 1e-300)
    # forward and down: under the chin, on a head open at the neck (a level loop) and on a face
    # scan open around the face alike.  Not the vertex furthest that way, which jumps from end
    # to end of a flat side (a neck cut square) when the direction turns a degree, but where a
    # ray from the loop's centre that way, in the loop's plane, leaves the loop.
    P = V[loop]
    c = P.mean(0)
    n = np.linalg.svd(P - c, full_matrices=False)[2][2]
    e1 = d - (d @ n) * n
    if np.linalg.norm(e1) < 1e-9 * max(np.linalg.norm(d), 1e-300):
        return int(loop[np.argmax(P @ d)])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    x, y = (P - c) @ e1, (P - c) @ e2
    x2, y2 = np.roll(x, -1), np.roll(y, -1)
    # loop edges the ray (y = 0, x > 0) crosses; the crossing furthest out
    cross = (np.sign(y) != np.sign(y2)) | (y == 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(y != y2, y / (y - y2), 0.0)
    xc = x + t * (x2 - x)
    ok = cross & (xc > 0)
    if not ok.any():
        return int(loop[np.argmax(P @ d)])
    k = int(np.flatnonzero(ok)[np.argmax(xc[ok])])
    return int(loop[k] if t[k] <= 0.5 else loop[(k + 1) % len(loop)])


def _split(V: np.ndarray, loop: np.ndarray, start: int, fractions: np.ndarray) -> np.ndarray:
    """Boundary vertices nearest to the given arc-length fractions, starting at ``start``."""
    k = int(np.flatnonzero(loop == start)[0])
    lp = np.roll(loop, -k)
    s, L = boundary_arclength(V, lp)
    idx = []
    for fr in np.mod(fractions, 1.0):
        target = fr * L
        d = np.abs(s - target)
        d = np.minimum(d, L - d)
        idx.append(int(np.argmin(d)))
    idx = np.array(idx)
    if len(np.unique(idx)) != len(idx):
        raise ParameterizationError("boundary too short to place distinct corners")
    return lp[idx]


def _loop(V, F) -> np.ndarray:
    V, F = check_mesh(V, F)
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"need exactly one boundary loop; got {len(loops)}")
    return loops[0]


#: where corner 0 sits relative to the reference vertex, and the others after it (fractions
#: of the boundary's length, in boundary order): the reference lands mid-way along the first
#: side, so the face is centred and upright in the default image
_BASE = np.array([-1.0, 1.0, 3.0, 5.0]) / 8.0


def default_corners(V, F, reference: int | None = None, front=None, up=None) -> np.ndarray:
    """The default four corners: the boundary split into four equal arcs with the
    ``reference`` vertex in the middle of the first (corner 0 → corner 1, the bottom side of
    the rectangle).

    ``reference`` defaults to the boundary vertex where a ray from the boundary's centre along
    ``front − up`` (in the boundary's plane; default ``front`` +Z, ``up`` +Y: forward and down)
    leaves it: under the chin of a head open at the neck, or the chin of a face scan, so the
    face is upright and centred.  Returned in
    boundary order (counter-clockwise in the map).
    """
    return corner_sets(V, F, n=1, reference=reference, front=front, up=up)[0]


def corner_sets(V, F, n: int = 8, reference: int | None = None, front=None, up=None, count: int | None = None,
                turn: float = 0.0) -> list[np.ndarray]:
    """The paper's augmentation: ``n`` different corner sets, each splitting the boundary
    into four equal arcs, set ``k`` turned ``k / (4n)`` of the boundary further than set 0
    (:func:`default_corners`).

    With ``n = 8`` the sets are turned by 1/32 of the boundary each, so the eight sets are
    eight different vertex sets — eight different conformal maps, not rotations of one
    image.  On a boundary too coarse for that, a set that would repeat an earlier one is
    moved along the boundary by whole vertices until it differs, and where no such turn is new
    (a boundary of a dozen vertices) one or two of its corners move on their own.  ``count``: only the first
    ``count`` of the ``n`` sets (default all).  ``turn``: every set turned a further ``turn`` of
    the boundary's length (in boundary order; ``geoface convert`` turns them so that the face's eye
    line comes out level).
    """
    if int(n) != n or n < 1:
        raise ParameterizationError(f"n must be a positive integer; got {n!r}")
    V = np.asarray(V, np.float64)
    loop = _loop(V, F)
    start = _reference(V, loop, reference, front, up)
    sets: list[np.ndarray] = []
    seen: set = set()
    pos = {int(v): i for i, v in enumerate(loop)}
    for k in range(int(n) if count is None else min(int(count), int(n))):
        c = _split(V, loop, start, _BASE + k / (4.0 * n) + float(turn))
        shift = 0
        while frozenset(c.tolist()) in seen and shift < len(loop):
            shift += 1
            c = np.array([loop[(pos[int(v)] + 1) % len(loop)] for v in c])
        if frozenset(c.tolist()) in seen:
            # a short boundary (a few dozen vertices) has only a few evenly spaced sets: move
            # single corners instead, the smallest moves first
            c = _uneven_set(loop, pos, sets[0], seen)
        if c is None:
            raise ParameterizationError(f"the boundary ({len(loop)} vertices) is too short for {n} different corner sets")
        seen.add(frozenset(c.tolist()))
        sets.append(c)
    return sets


def _uneven_set(loop, pos, base, seen):
    """A corner set not in ``seen``: ``base`` with one or two corners moved along the boundary
    by a few vertices, keeping the four in boundary order and distinct; None if there is none."""
    m = len(loop)
    p0 = np.array([pos[int(v)] for v in base])
    moves = sorted(((a, b) for a in range(-m // 8 - 1, m // 8 + 2) for b in range(-m // 8 - 1, m // 8 + 2)),
                   key=lambda ab: (abs(ab[0]) + abs(ab[1]), ab))
    for j in range(4):
        for a, b in moves:
            p = p0.copy()
            p[j] = p[j] + a
            p[(j + 2) % 4] = p[(j + 2) % 4] + b
            rel = (p - p[0]) % m
            if len(set((p % m).tolist())) < 4 or rel.tolist() != sorted(rel.tolist()):
                continue
            c = np.asarray(loop[p % m])
            if frozenset(c.tolist()) not in seen:
                return c
    return None
