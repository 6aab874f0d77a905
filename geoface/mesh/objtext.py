"""OBJ text written by array operations: ``v``/``vt``/``f`` lines with no Python call per number.

A 512² reconstruction (262K vertices and UVs, 522K faces) takes about 0.3 s instead of 2.9 s
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
    powers = 10 ** np.arange(width - 1, -1, -1, dtype=np.int64)
    return ((q[:, None] // powers) % 10 + 48).astype(np.uint8)


def _strip_leading(d: np.ndarray, keep: int) -> np.ndarray:
    """Leading '0's of each row turned into padding, keeping at least ``keep`` digits."""
    head = d[:, : d.shape[1] - keep]
    lead = np.cumsum(head != 48, axis=1) == 0
    head[lead] = 0
    return d


def fixed_columns(x: np.ndarray, digits: int) -> np.ndarray:
    """(n, w) bytes of ``x`` written with ``digits`` decimals (0 bytes are padding)."""
    x = np.asarray(x, np.float64)
    q = np.rint(np.abs(x) * 10.0**digits).astype(np.int64)
    width = max(len(str(int(q.max(initial=0)))), digits + 1)
    d = _digit_matrix(q, width)
    whole, frac = d[:, : width - digits], d[:, width - digits:]
    whole = _strip_leading(whole, 1)
    sign = np.where((x < 0) & (q > 0), ord("-"), 0).astype(np.uint8)[:, None]
    dot = np.full((len(x), 1), ord("."), np.uint8)
    return np.hstack([sign, whole, dot, frac] if digits else [sign, whole])


def int_columns(a: np.ndarray) -> np.ndarray:
    """(n, w) bytes of the non-negative integers ``a``."""
    a = np.asarray(a, np.int64)
    width = len(str(int(a.max(initial=0))))
    return _strip_leading(_digit_matrix(a, width), 1)


def _lines(prefix: str, columns: list, seps: str = "") -> bytes:
    """One line per row: ``prefix``, the columns separated by ``seps[i]`` (default spaces)."""
    n = len(columns[0])
    seps = seps or " " * (len(columns) - 1)

    def const(text: str) -> np.ndarray:
        return np.frombuffer(text.encode(), np.uint8)[None].repeat(n, 0)

    parts = [const(prefix)]
    for i, c in enumerate(columns):
        if i:
            parts.append(const(seps[i - 1]))
        parts.append(c)
    parts.append(np.full((n, 1), ord("\n"), np.uint8))
    m = np.hstack(parts).ravel()
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
