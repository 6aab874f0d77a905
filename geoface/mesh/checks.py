"""Mesh arrays checked once: :func:`check_mesh` validates a user's ``(V, F)`` at a public entry,
and :func:`checked_meshes` marks the steps below the entry, which work on meshes derived from
it (``check_mesh`` only converts there, and :func:`geoface.mesh.core.edge_topology` is built once
per set of faces)."""

from __future__ import annotations

import contextlib
import contextvars

import numpy as np

from ..errors import InvalidMeshError

__all__ = ["CHECKS", "MAX_COORDINATE", "check_mesh", "checked_meshes"]


#: the largest coordinate magnitude accepted (its square and sums of squares stay finite)
MAX_COORDINATE = 1e150


class _Checks:
    """How many meshes :func:`check_mesh` validated and how many edge topologies were built (a
    test counts them per ``convert``)."""
    validations = 0
    topologies = 0


CHECKS = _Checks()
#: inside :func:`checked_meshes`: the edge topologies built so far, by the faces' content
CHECKED_SCOPE: contextvars.ContextVar = contextvars.ContextVar("geoface_checked_meshes", default=None)
TOPOLOGY_CACHE_SIZE = 32


@contextlib.contextmanager
def checked_meshes():
    """The library's own meshes from here on: a public entry (``convert``, ``make_disk``, the face
    finder) validates the user's mesh once with :func:`check_mesh`, then runs its steps inside
    this scope, where ``check_mesh`` only converts dtypes (every mesh is one the entry checked or
    a step derived from it) and :func:`edge_topology` is built once per set of faces. Nests."""
    if CHECKED_SCOPE.get() is not None:
        yield
        return
    token = CHECKED_SCOPE.set({})
    try:
        yield
    finally:
        CHECKED_SCOPE.reset(token)


def check_mesh(V, F, *, allow_empty: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert mesh arrays once, at a public entry point (inside
    :func:`checked_meshes`, convert only: the entry has validated them).

    Parameters
    ----------
    V : array_like, (n, 3) float
    F : array_like, (m, 3) int

    Returns
    -------
    V : (n, 3) float64, F : (m, 3) int64

    Raises
    ------
    InvalidMeshError
        Wrong shapes, non-finite coordinates, negative or out-of-range indices, no faces.

    Examples
    --------
    >>> V, F = check_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> V.dtype, F.dtype
    (dtype('float64'), dtype('int64'))
    """
    if CHECKED_SCOPE.get() is not None and isinstance(V, np.ndarray) and isinstance(F, np.ndarray) \
            and V.ndim == 2 and F.ndim == 2 and F.dtype.kind in "iu":
        return np.asarray(V, dtype=np.float64), F.astype(np.int64, copy=False)
    CHECKS.validations += 1
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidMeshError(f"V must be a numeric (n, 3) array; {exc}") from None
    Fa = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InvalidMeshError(f"V must have shape (n, 3); got {V.shape}")
    if Fa.size == 0 and Fa.ndim <= 2:
        Fa = Fa.reshape(0, 3)
    if Fa.ndim != 2 or Fa.shape[1] != 3:
        raise InvalidMeshError(f"F must have shape (m, 3); got {Fa.shape}")
    if Fa.dtype == bool or Fa.dtype.kind not in "iufO":
        raise InvalidMeshError(f"F must hold integer vertex indices; got an array of {Fa.dtype}")
    if Fa.dtype.kind in "iu" and Fa.dtype.itemsize < 4 and len(V) - 1 > np.iinfo(Fa.dtype).max:
        raise InvalidMeshError(f"F is {Fa.dtype}, which cannot index {len(V)} vertices (indices over "
                               f"{np.iinfo(Fa.dtype).max} have wrapped); pass int32 or int64 indices")
    if Fa.size and not np.issubdtype(Fa.dtype, np.integer):
        if not np.all(np.isfinite(Fa)) or np.any(Fa != np.round(Fa)):
            raise InvalidMeshError("F must hold integer vertex indices")
    F = Fa.astype(np.int64, copy=False)
    if not allow_empty and (len(V) == 0 or len(F) == 0):
        raise InvalidMeshError(f"mesh is empty: {len(V)} vertices, {len(F)} faces")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise InvalidMeshError(f"V has {int(bad.sum())} vertices with NaN or infinite coordinates (first: {int(np.flatnonzero(bad)[0])})")
    if len(V) and float(np.abs(V).max()) > MAX_COORDINATE:
        raise InvalidMeshError(f"coordinates reach {float(np.abs(V).max()):.3g}: beyond {MAX_COORDINATE:g} squared distances "
                               "overflow; rescale the mesh")
    if len(F):
        lo, hi = int(F.min()), int(F.max())
        if lo < 0 or hi >= len(V):
            raise InvalidMeshError(f"F indexes vertices in [{lo}, {hi}] but V has {len(V)} vertices")
    return V, F
