"""Aligning corresponding point sets."""
from __future__ import annotations

import numpy as np

__all__ = ["similarity_transform"]


def similarity_transform(P, Q, mask=None) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t): the similarity (uniform scale ``s``, rotation ``R`` [3, 3], translation ``t`` [3])
    that best maps points ``P`` onto corresponding points ``Q`` (both [n, 3]) in the least-squares
    sense, ``s R p + t ≈ q`` (Umeyama 1991; a reflection is never returned); ``mask`` [n]: the
    pairs to fit on (default all).  With fewer than 3 pairs, or all of them at one point, the
    identity.

    >>> P = np.random.default_rng(0).normal(size=(10, 3))
    >>> s, R, t = similarity_transform(P, 2 * P + 1)
    >>> bool(np.isclose(s, 2) and np.allclose(R, np.eye(3)) and np.allclose(t, 1))
    True
    """
    P, Q = np.asarray(P, np.float64), np.asarray(Q, np.float64)
    m = np.ones(len(P), bool) if mask is None else np.asarray(mask, bool)
    if m.sum() < 3:
        return 1.0, np.eye(3), np.zeros(3)
    a, b = P[m], Q[m]
    mu_a, mu_b = a.mean(0), b.mean(0)
    a0, b0 = a - mu_a, b - mu_b
    var_a = (a0**2).sum() / len(a)
    if not var_a > 0:
        return 1.0, np.eye(3), np.zeros(3)
    U, d, Vt = np.linalg.svd(b0.T @ a0 / len(a))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0
    R = U @ D @ Vt
    s = float(np.trace(np.diag(d) @ D) / var_a)
    return s, R, mu_b - s * R @ mu_a
