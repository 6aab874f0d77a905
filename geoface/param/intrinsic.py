"""Intrinsic operators over edge lengths (not positions).

Ricci flow and other conformal methods change lengths, not positions, so everything here
takes ``l (m, 3)``: ``l[f, k]`` is the length of the edge *opposite* corner ``k`` of face
``f``, i.e. between ``F[f, (k+1) % 3]`` and ``F[f, (k+2) % 3]``.

Triangles violating the triangle inequality are handled by the standard continuous
extension (Bobenko, Pinkall & Springborn 2015): the angle opposite the too-long edge is
pi and the other two are 0, their cotangent weights are 0.  Nothing here returns NaN.

>>> import numpy as np
>>> from geoface.synth import square_grid
>>> V, F = square_grid(5)
>>> l = edge_lengths(V, F)
>>> np.allclose(angle_sums(l, F, len(V))[12], 2 * np.pi)   # a flat interior vertex
True
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..mesh.core import boundary_loops


def edge_lengths(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``(m, 3)`` lengths; column ``k`` is the edge opposite corner ``k``."""
    return np.linalg.norm(V[F[:, [2, 0, 1]]] - V[F[:, [1, 2, 0]]], axis=2)


def _valid(l: np.ndarray) -> np.ndarray:
    """Triangles that satisfy the strict triangle inequality, ``(m,)`` bool."""
    a, b, c = l[:, 0], l[:, 1], l[:, 2]
    return (a < b + c) & (b < c + a) & (c < a + b)


def corner_angles(l: np.ndarray) -> np.ndarray:
    """Interior angles ``(m, 3)`` at each corner from the lengths (law of cosines).

    Uses the half-angle form ``tan(a/2) = sqrt((s-b)(s-c) / (s (s-a)))``, accurate for
    needle and cap triangles; degenerate triangles get angles (pi, 0, 0).
    """
    l = np.asarray(l, np.float64)
    s = 0.5 * l.sum(1, keepdims=True)
    d = s - l  # (s-a, s-b, s-c)
    ok = _valid(l)
    ang = np.zeros_like(l)
    if ok.any():
        dd = d[ok]
        ss = s[ok]
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                num = dd[:, (k + 1) % 3] * dd[:, (k + 2) % 3]
                den = ss[:, 0] * dd[:, k]
                # den == 0 only at the triangle-inequality limit: angle pi
                ang[ok, k] = np.where(den > 0, 2.0 * np.arctan(np.sqrt(num / np.where(den > 0, den, 1.0))), np.pi)
    if (~ok).any():
        bad = np.flatnonzero(~ok)
        kmax = np.argmax(l[bad], axis=1)
        ang[bad, kmax] = np.pi
    return ang


def angle_sums(l: np.ndarray, F: np.ndarray, n: int) -> np.ndarray:
    """Sum of corner angles at each vertex, ``(n,)``."""
    return np.bincount(F.ravel(), weights=corner_angles(l).ravel(), minlength=n)


def boundary_mask(F: np.ndarray, n: int) -> np.ndarray:
    """``(n,)`` bool: vertices on a boundary loop."""
    b = np.zeros(n, bool)
    for lp in boundary_loops(F):
        b[lp] = True
    return b


def curvature(l: np.ndarray, F: np.ndarray, n: int, boundary: np.ndarray | None = None) -> np.ndarray:
    """Discrete curvature per vertex: ``2 pi - angle sum`` inside (Gaussian curvature),
    ``pi - angle sum`` on the boundary (geodesic curvature).

    Gauss-Bonnet: ``curvature(...).sum() == 2 pi chi`` for any lengths (exactly).
    """
    b = boundary_mask(F, n) if boundary is None else boundary
    theta = angle_sums(l, F, n)
    return np.where(b, np.pi, 2 * np.pi) - theta


def face_area(l: np.ndarray) -> np.ndarray:
    """Heron's formula (stable form); 0 for degenerate triangles."""
    a, b, c = np.sort(l, axis=1)[:, ::-1].T  # a >= b >= c
    q = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * np.sqrt(np.maximum(q, 0.0))


def cotan_weights(l: np.ndarray) -> np.ndarray:
    """``(m, 3)`` cotangents of the corner angles (0 for degenerate triangles).

    ``cot a = (b^2 + c^2 - a^2) / (4 A)``.
    """
    l2 = l * l
    A = face_area(l)
    ok = A > 0
    out = np.zeros_like(l)
    for k in range(3):
        num = l2[:, (k + 1) % 3] + l2[:, (k + 2) % 3] - l2[:, k]
        out[ok, k] = num[ok] / (4.0 * A[ok])
    return out


def cotan_laplacian(l: np.ndarray, F: np.ndarray, n: int) -> sp.csr_matrix:
    """Positive semi-definite cotangent Laplacian ``L`` (``n x n``, rows sum to 0).

    ``L_ij = -(cot a_ij + cot b_ij) / 2`` for an edge ``ij`` with opposite angles
    ``a_ij, b_ij``; ``L_ii = -sum_j L_ij``.  For flat lengths, ``x^T L x`` is the Dirichlet
    energy of the piecewise linear function ``x``.
    """
    w = 0.5 * cotan_weights(l)
    i = F[:, [1, 2, 0]].ravel()
    j = F[:, [2, 0, 1]].ravel()
    ww = w.ravel()
    rows = np.concatenate([i, j, i, j])
    cols = np.concatenate([j, i, i, j])
    vals = np.concatenate([-ww, -ww, ww, ww])
    return sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()


def clausen2(x: np.ndarray) -> np.ndarray:
    """Clausen function ``Cl2(x) = -int_0^x log|2 sin(t/2)| dt`` (vectorised, ~1e-15).

    Reduced to ``[0, pi]`` by oddness and 2 pi periodicity, then the series
    ``x - x log x + sum_n |B_2n| x^(2n+1) / (2n (2n+1)!)`` (converges for ``|x| < 2 pi``).
    """
    x = np.asarray(x, np.float64)
    y = np.mod(x + np.pi, 2 * np.pi) - np.pi  # (-pi, pi]
    sgn = np.sign(y)
    t = np.abs(y)
    out = np.zeros_like(t)
    nz = t > 0
    tt = t[nz]
    acc = tt - tt * np.log(tt)
    p = tt.copy()
    t2 = tt * tt
    for coef in _CL2_COEF:
        p = p * t2
        acc = acc + coef * p
    out[nz] = acc
    return sgn * out


def _cl2_coefficients(N: int = 40) -> np.ndarray:
    from fractions import Fraction
    from math import comb, factorial

    # Bernoulli numbers B_0..B_2N (exact, Akiyama-Tanigawa is overkill; use the recurrence)
    B = [Fraction(1)]
    for m in range(1, 2 * N + 1):
        B.append(-sum(comb(m + 1, k) * B[k] for k in range(m)) / (m + 1))
    return np.array([float(abs(B[2 * n]) / (2 * n * factorial(2 * n + 1))) for n in range(1, N + 1)])


_CL2_COEF = _cl2_coefficients()


def lobachevsky(x: np.ndarray) -> np.ndarray:
    """Milnor's Lobachevsky function ``Л(x) = -int_0^x log|2 sin t| dt = Cl2(2x) / 2``."""
    return 0.5 * clausen2(2.0 * np.asarray(x, np.float64))
