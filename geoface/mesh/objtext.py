"""OBJ text written by array operations: ``v``/``vt``/``f`` lines with no Python call per number.

A 512² reconstruction (262K vertices and UVs, 522K faces) takes about 0.2 s instead of 2.9 s
with ``str.format`` (trimesh).  Numbers are fixed-point with ``digits`` decimals, like ``%.*f``
(the last decimal can differ by one where ``x · 10^digits`` rounds the other way in binary).
Each number becomes a row of ASCII digits in a byte matrix; the padding (leading zeros, the
sign of a positive number) is a 0 byte that is dropped when the lines are joined.
"""

from __future__ import annotations

import numpy as np

#: the fast path writes ``round(|x| · 10^digits)`` as int64 digits: up to 18 decimals
MAX_DIGITS = 18


def _digit_matrix(q: np.ndarray, width: int) -> np.ndarray:
    """(n, width) ASCII digits of the non-negative int64 ``q``, zero-padded on the left."""
    # one column at a time, by a scalar 10: NumPy divides by a scalar with libdivide, ~13x faster
    # than dividing by a broadcast row of powers of ten
    out = np.empty((len(q), width), np.uint8)
    r = np.asarray(q, np.int64)
    for k in range(width - 1, -1, -1):
        nr = r // 10
        out[:, k] = (r - nr * 10).astype(np.uint8) + 48
        r = nr
    return out


def _strip_leading(d: np.ndarray, q: np.ndarray, keep: int) -> np.ndarray:
    """Leading '0's of each row of ``d`` (the digits of ``q``) turned into padding, keeping at
    least ``keep`` digits: column ``k`` is padding where ``q < 10^(width - 1 - k)``."""
    width = d.shape[1]
    for k in range(width - keep):
        d[q < 10 ** (width - 1 - k), k] = 0
    return d


def fixed_columns(x: np.ndarray, digits: int) -> np.ndarray:
    """(n, w) bytes of ``x`` written with ``digits`` decimals (0 bytes are padding)."""
    x = np.asarray(x, np.float64)
    q = np.rint(np.abs(x) * 10.0**digits).astype(np.int64)
    width = max(len(str(int(q.max(initial=0)))), digits + 1)
    d = _digit_matrix(q, width)
    whole, frac = d[:, : width - digits], d[:, width - digits:]
    whole = _strip_leading(whole, q // 10**digits, 1)
    sign = np.where((x < 0) & (q > 0), ord("-"), 0).astype(np.uint8)[:, None]
    dot = np.full((len(x), 1), ord("."), np.uint8)
    return np.hstack([sign, whole, dot, frac] if digits else [sign, whole])


def int_columns(a: np.ndarray) -> np.ndarray:
    """(n, w) bytes of the non-negative integers ``a``."""
    a = np.asarray(a, np.int64)
    width = len(str(int(a.max(initial=0))))
    return _strip_leading(_digit_matrix(a, width), a, 1)


def _lines(prefix: str, columns: list, seps: str = "") -> bytes:
    """One line per row: ``prefix``, the columns separated by ``seps[i]`` (default spaces)."""
    n = len(columns[0])
    seps = seps or " " * (len(columns) - 1)
    pieces: list = [prefix.encode()]
    for i, c in enumerate(columns):
        if i:
            pieces.append(seps[i - 1].encode())
        pieces.append(c)
    pieces.append(b"\n")
    width = sum(len(p) if isinstance(p, bytes) else p.shape[1] for p in pieces)
    m = np.empty((n, width), np.uint8)  # filled column block by column block: no stacked copies
    at = 0
    for p in pieces:
        w = len(p) if isinstance(p, bytes) else p.shape[1]
        m[:, at: at + w] = np.frombuffer(p, np.uint8) if isinstance(p, bytes) else p
        at += w
    m = m.ravel()
    return m[m != 0].tobytes()


def obj_body(V: np.ndarray, F: np.ndarray, UV: np.ndarray | None, digits: int) -> bytes:
    """``v`` lines, ``vt`` lines (when ``UV``: one per vertex, indexed like ``V``) and ``f`` lines
    (1-based; ``a/a`` pairs with UVs)."""
    out = [_lines("v ", [fixed_columns(V[:, k], digits) for k in range(3)])] if len(V) else []
    if UV is not None and len(UV):
        out.append(_lines("vt ", [fixed_columns(UV[:, k], digits) for k in range(2)]))
    if len(F):
        idx = [int_columns(F[:, k] + 1) for k in range(3)]
        if UV is not None:
            out.append(_lines("f ", [idx[0], idx[0], idx[1], idx[1], idx[2], idx[2]], seps="/ / /"))
        else:
            out.append(_lines("f ", idx))
    return b"".join(out)
