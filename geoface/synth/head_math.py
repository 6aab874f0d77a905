"""Small fields the procedural head is built from (:mod:`geoface.synth.head_shape`): smooth
steps, Gaussian bumps, ray directions, colour mixing, and the bands of the mouth crease shared
by the shape, its expressions and its colours."""
from __future__ import annotations

import numpy as np


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def gauss2(a, b, sa, sb):
    return np.exp(-0.5 * ((a / sa) ** 2 + (b / sb) ** 2))


def sphere_dirs(theta, phi):
    """Unit directions; theta from +Y, phi from +Z toward +X."""
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), st * np.cos(phi)], axis=-1)


def mix_colors(C, col, w):
    """``C * (1 - w) + col * w`` (in place where ``w > 0``); ``col`` is (3,) or per-row (k, 3)."""
    w = np.asarray(w, dtype=np.float64)
    idx = np.flatnonzero(w > 0.0)
    if len(idx) == 0:
        return C
    col = np.asarray(col, dtype=np.float64)
    col = col[idx] if col.ndim == 2 else col
    wi = np.minimum(w[idx], 1.0)[:, None]
    C[idx] = C[idx] * (1.0 - wi) + col * wi
    return C


# mouth crease width (chart metres): the crease walls become the inside of the mouth when it opens;
# t = y - mouth_line: upper lip inside > T_UT > upper teeth > T_CU > cavity > T_CL > lower teeth > T_LT
SIG_C = 0.0015
T_UT, T_CU, T_CL, T_LT = 1.1 * SIG_C, 0.35 * SIG_C, -0.5 * SIG_C, -1.0 * SIG_C
