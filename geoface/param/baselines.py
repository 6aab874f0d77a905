"""Baselines through libigl: harmonic map to the same rectangle boundary, and LSCM.

>>> from geoface.synth import spherical_cap
>>> V, F = spherical_cap(1.0, 1.0, 8)
>>> uv = harmonic_rectangle(V, F)
>>> uv.shape
(217, 2)
"""

from __future__ import annotations

import time

import numpy as np

from .._lazy import lazy_import
from ..errors import ParameterizationError
from ..mesh.core import boundary_loops, check_mesh
from .corners import boundary_arclength, default_corners


def square_boundary(V: np.ndarray, loop: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Place the boundary on the unit square: corners at its corners, each side's vertices
    spaced by arc length (the boundary condition of the harmonic baseline)."""
    pos = {int(v): i for i, v in enumerate(loop)}
    k0 = pos[int(corners[0])]
    lp = np.roll(loop, -k0)
    s, L = boundary_arclength(V, lp)
    cidx = [int(np.flatnonzero(lp == c)[0]) for c in corners] + [len(lp)]
    sq = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
    uv = np.zeros((len(lp), 2))
    s_ext = np.r_[s, L]
    for side in range(4):
        a, b = cidx[side], cidx[side + 1]
        t = (s_ext[a:b] - s_ext[a]) / (s_ext[b] - s_ext[a])
        uv[a:b] = sq[side] + t[:, None] * (sq[side + 1] - sq[side])
    return lp, uv


def harmonic_rectangle(V, F, corners=None) -> np.ndarray:
    """Harmonic (cotangent) map with the boundary fixed on the unit square by arc length."""
    igl = lazy_import("igl", "the harmonic baseline")
    V, F = check_mesh(V, F)
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"need a disk; got {len(loops)} boundary loops")
    corners = default_corners(V, F) if corners is None else np.asarray(corners, np.int64)
    b, bc = square_boundary(V, loops[0], corners)
    return np.asarray(igl.harmonic(V, F, b.astype(np.int64), bc, 1), np.float64)


def lscm(V, F) -> np.ndarray:
    """Least-squares conformal map (free boundary), two boundary vertices pinned, scaled to
    the unit square's size."""
    igl = lazy_import("igl", "the LSCM baseline")
    V, F = check_mesh(V, F)
    loops = boundary_loops(F)
    if len(loops) != 1:
        raise ParameterizationError(f"need a disk; got {len(loops)} boundary loops")
    lp = loops[0]
    b = np.array([lp[0], lp[len(lp) // 2]], np.int64)
    bc = np.array([[0.0, 0.0], [1.0, 0.0]])
    out = igl.lscm(V, F, b, bc)
    uv = out[0] if isinstance(out, tuple) else out
    return np.asarray(uv, np.float64)


def timed(fn, *a, **k):
    t = time.perf_counter()
    out = fn(*a, **k)
    return out, time.perf_counter() - t
