"""Exact 2D regular triangulations (the dual of power diagrams), from CGAL.

``regular_triangulation(X, w)`` returns the counter-clockwise triangles of the regular
triangulation of weighted points ``X (n, 2)``, ``w (n,)`` (power ``|x - p|² - w``) and their
neighbours.  Every orientation and power test is decided exactly (CGAL's filtered exact
predicates), so sites far closer together than floating-point arithmetic resolves still
become vertices with their own cells; points whose weight is too low to own any part of
the plane are simply absent ("hidden").

The triangulation comes from a small compiled extension against CGAL's headers
(Debian's ``libcgal-dev``; ``make install`` sets it up and ``pip install -e .`` builds it).
:func:`available` tells whether it is there; :func:`require` raises with an install hint.

>>> import numpy as np
>>> if available():
...     T, N = regular_triangulation(np.array([[0., 0.], [1., 0.], [0., 1.], [1., 1.]]), np.zeros(4))
...     print(T.shape, (N >= -1).all())
... else:
...     print((2, 3), True)
(2, 3) True
"""

from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._lazy import native_library
from ..errors import GeofaceError, ParameterizationError

__all__ = ["available", "require", "regular_triangulation", "spatial_order", "flip_to_regular", "power_cells", "power_sides", "power_centres", "INSTALL_HINT"]

INSTALL_HINT = ("install CGAL's headers (Debian/Ubuntu: apt-get install libcgal-dev; conda: cgal-cpp) and rebuild "
                "geoface (make install, or pip install -e .)")


@lru_cache(maxsize=1)
def _lib():
    lib = native_library(Path(__file__).with_name("_native"), "regular_triangulation", "geoface_rt2_abi")
    if lib is not None:
        lib.geoface_rt2.restype = ctypes.c_int64
        lib.geoface_rt2.argtypes = [ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64,
                                    ctypes.c_void_p, ctypes.c_void_p]
        if hasattr(lib, "geoface_rt2_ordered"):  # absent from extensions built before it
            lib.geoface_spatial_order.restype = ctypes.c_int64
            lib.geoface_spatial_order.argtypes = [ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p]
            lib.geoface_rt2_ordered.restype = ctypes.c_int64
            lib.geoface_rt2_ordered.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 3 + [ctypes.c_int64] + [ctypes.c_void_p] * 2
        if hasattr(lib, "geoface_rt2_flip"):  # absent from extensions built before it
            lib.geoface_rt2_flip.restype = ctypes.c_int64
            lib.geoface_rt2_flip.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 2 + [ctypes.c_int64] + \
                [ctypes.c_void_p] * 2 + [ctypes.c_int64]
        if hasattr(lib, "geoface_power_cells"):  # absent from extensions built before it
            lib.geoface_power_cells.restype = ctypes.c_int64
            lib.geoface_power_cells.argtypes = [ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64] + [ctypes.c_void_p] * 7
        if hasattr(lib, "geoface_power_sides"):
            lib.geoface_power_sides.restype = None
            lib.geoface_power_sides.argtypes = [ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64] + [ctypes.c_void_p] * 3
        if hasattr(lib, "geoface_power_centres"):
            lib.geoface_power_centres.restype = ctypes.c_int64
            lib.geoface_power_centres.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 4
    return lib


def available() -> bool:
    """Whether the exact (CGAL) regular triangulation is built and loads."""
    return _lib() is not None


def require() -> None:
    """Raise :class:`GeofaceError` with an install hint when CGAL is not available."""
    if not available():
        raise GeofaceError(f"exact power diagrams need geoface's CGAL extension: {INSTALL_HINT}")


def spatial_order(X, first=()) -> np.ndarray | None:
    """An insertion order for :func:`regular_triangulation` over the points ``X (n, 2)``: the
    indices ``first`` as given, then the others in CGAL's spatial (Hilbert) order — the sort a
    range insertion does on every call.  Sites that keep their places while their weights change
    (a Newton solve) sort once.  None when the extension predates it."""
    fn = _compiled("geoface_spatial_order")
    if fn is None or not hasattr(_lib(), "geoface_rt2_ordered"):
        return None
    X = np.ascontiguousarray(X, np.float64)
    first = np.asarray(first, np.int64)
    rest = np.ones(len(X), bool)
    rest[first] = False
    rest = np.flatnonzero(rest)
    Xr = np.ascontiguousarray(X[rest])
    order = np.empty(len(rest), np.int64)
    if fn(len(rest), Xr.ctypes.data, order.ctypes.data) != 0:
        return None
    return np.concatenate([first, rest[order]])


def regular_triangulation(X, w, order=None) -> tuple[np.ndarray, np.ndarray]:
    """Regular triangulation of ``X (n, 2)`` with weights ``w (n,)``.  ``order``: the insertion
    order (from :func:`spatial_order`; by default CGAL sorts the points itself).

    Returns
    -------
    T : (m, 3) int64 — counter-clockwise triangles (point indices)
    N : (m, 3) int64 — ``N[t, k]``: the triangle across the edge opposite ``T[t, k]``
        (-1 on the convex hull)
    """
    lib = _lib()
    if lib is None:
        require()
    X = np.ascontiguousarray(X, np.float64)
    w = np.ascontiguousarray(w, np.float64)
    n = len(X)
    if X.shape != (n, 2) or w.shape != (n,):
        raise ParameterizationError(f"regular_triangulation needs X (n, 2) and w (n,); got {X.shape}, {w.shape}")
    if not (np.isfinite(X).all() and np.isfinite(w).all()):
        raise ParameterizationError("points or weights contain NaN or infinite values")
    cap = 2 * n + 8
    T = np.empty((cap, 3), np.int64)
    N = np.empty((cap, 3), np.int64)
    if order is None:
        m = lib.geoface_rt2(n, X.ctypes.data, w.ctypes.data, cap, T.ctypes.data, N.ctypes.data)
    else:
        order = np.ascontiguousarray(order, np.int64)
        if order.shape != (n,):
            raise ParameterizationError(f"order must have shape ({n},); got {order.shape}")
        m = lib.geoface_rt2_ordered(n, X.ctypes.data, w.ctypes.data, order.ctypes.data, cap, T.ctypes.data, N.ctypes.data)
    if m == -1:
        raise ParameterizationError("regular triangulation failed: fewer than three affinely independent points")
    if m < 0:  # cannot happen (a planar triangulation has at most 2n - 5 triangles); be safe
        raise ParameterizationError(f"regular triangulation has {-m} triangles, more than {cap}")
    return T[:m], N[:m]  # views: no copy of ~40 bytes a triangle


def flip_to_regular(X, w, T, N, max_flips: int | None = None) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Lawson flips, with exact predicates, from the regular triangulation ``T``, ``N`` of the
    points ``X`` under other weights (every point a vertex; as :func:`regular_triangulation`
    returns them) to the one of the weights ``w``.  Returns new ``(T, N, flips)``, or None when
    the flips cannot get there (a point must disappear), after ``max_flips`` (default: one per
    triangle; triangulating anew is then cheaper), or when the extension predates it."""
    fn = _compiled("geoface_rt2_flip")
    if fn is None:
        return None
    X, w = _f64(X, w)
    T = np.array(T, np.int64, order="C", copy=True)
    N = np.array(N, np.int64, order="C", copy=True)
    if X.shape != (len(w), 2) or T.ndim != 2 or T.shape[1:] != (3,) or N.shape != T.shape:
        raise ParameterizationError(f"flip_to_regular needs X (n, 2), w (n,), T and N (m, 3); got {X.shape}, {w.shape}, "
                                    f"{T.shape}, {N.shape}")
    k = fn(len(X), X.ctypes.data, w.ctypes.data, len(T), T.ctypes.data, N.ctypes.data,
           len(T) if max_flips is None else int(max_flips))
    return None if k < 0 else (T, N, int(k))


def _compiled(name: str):
    """The extension's function ``name``, or None (not built, or built before it existed)."""
    lib = _lib()
    return None if lib is None or not hasattr(lib, name) else getattr(lib, name)


def _f64(*arrays):
    return [np.ascontiguousarray(a, np.float64) for a in arrays]


def _i64(*arrays):
    return [np.ascontiguousarray(a, np.int64) for a in arrays]


def power_cells(n: int, Xa, T, N, cen):
    """The interior part of power cells clipped to ``[-0.5, 0.5]^2``, compiled: the dual edges of
    the regular triangulation ``T``, ``N`` (power centres ``cen``) of ``Xa`` (the ``n`` real
    sites, then guards), clipped and summed by the shoelace formula relative to each site.

    Returns ``(area (n,), moment (n, 2), edges (k, 2), lengths (k,))`` (the square's sides
    not yet added; moments relative to the sites), or None when the extension lacks it; the
    same arithmetic as :func:`geoface.param.power._cells`' NumPy path.
    """
    fn = _compiled("geoface_power_cells")
    if fn is None:
        return None
    Xa, cen = _f64(Xa, cen)
    T, N = _i64(T, N)
    m = len(T)
    if T.shape != (m, 3) or N.shape != (m, 3) or cen.shape != (m, 2) or Xa.ndim != 2 or Xa.shape[1] != 2 or len(Xa) < n:
        raise ParameterizationError("power_cells needs Xa (>= n, 2), T and N (m, 3), cen (m, 2)")
    area = np.zeros(n)
    mom = np.zeros((n, 2))
    cap = (3 * m) // 2 + 3
    E = np.empty((cap, 2), np.int64)
    L = np.empty(cap)
    k = fn(n, Xa.ctypes.data, m, T.ctypes.data, N.ctypes.data, cen.ctypes.data,
                                area.ctypes.data, mom.ctypes.data, E.ctypes.data, L.ctypes.data)
    return area, mom, E[:k], L[:k]


def power_sides(X, w, cand, area, mom) -> bool:
    """Add the square's sides' part of the power cells of sites ``X (n, 2)`` (re-centred on
    ``[-0.5, 0.5]^2``), weights ``w``, to ``area (n,)`` and ``mom (n, 2)`` in place, compiled:
    each side is split among the candidate sites ``cand`` by the lower envelope of their power
    along it (:func:`geoface.param.power._lower_envelope`'s arithmetic).  False (nothing added)
    when the extension lacks it."""
    fn = _compiled("geoface_power_sides")
    if fn is None:
        return False
    X, w = _f64(X, w)
    (cand,) = _i64(cand)
    n = len(X)
    if X.shape != (n, 2) or w.shape != (n,) or cand.ndim != 1 or area.shape != (n,) or mom.shape != (n, 2):
        raise ParameterizationError("power_sides needs X (n, 2), w (n,), cand (k,), area (n,), mom (n, 2)")
    if area.dtype != np.float64 or mom.dtype != np.float64 or not (area.flags.c_contiguous and mom.flags.c_contiguous):
        raise ParameterizationError("power_sides accumulates into C-contiguous float64 area and mom")
    if len(cand) and (cand.min() < 0 or cand.max() >= n):
        raise ParameterizationError("power_sides: candidate sites out of range")
    fn(n, X.ctypes.data, w.ctypes.data, len(cand), cand.ctypes.data, area.ctypes.data, mom.ctypes.data)
    return True


def power_centres(Xa, wa, T):
    """Power centres of the triangles ``T (m, 3)`` of weighted points ``Xa``, ``wa``, compiled
    (:func:`geoface.param.power_triangulation._power_centres`' arithmetic: NaN or infinity
    for a triangle too flat for double precision), and how many triangles have a
    floating-point signed area <= 0; None when the extension lacks it."""
    fn = _compiled("geoface_power_centres")
    if fn is None:
        return None
    Xa, wa = _f64(Xa, wa)
    (T,) = _i64(T)
    if Xa.ndim != 2 or Xa.shape[1] != 2 or wa.shape != (len(Xa),) or T.ndim != 2 or T.shape[1] != 3:
        raise ParameterizationError("power_centres needs Xa (n, 2), wa (n,), T (m, 3)")
    cen = np.empty((len(T), 2))
    flat = fn(len(T), Xa.ctypes.data, wa.ctypes.data, T.ctypes.data, cen.ctypes.data)
    return cen, int(flat)
