"""A decimated proxy of a large scan: the parameterization is solved on it, and everything the
images hold (positions, normals, colours) is sampled from the full surface.

:func:`decimate` is quadric edge collapse (fast-simplification, the pyvista project's wrapper of
Forstmann's fast quadric simplifier: a 4M-face scan in 8–14 s on one core, where pymeshlab's
quadric collapse takes 100 s); boundary edges only collapse into boundary vertices, so openings
keep their shape.

>>> from geoface.synth import sphere
>>> V, F = sphere(1.0, 4)
>>> r = decimate(V, F, 500)
>>> 400 <= len(r.V) <= 600
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._lazy import lazy_import
from ..errors import InvalidMeshError
from ..mesh.core import check_mesh

__all__ = ["decimate", "ProxyResult"]


@dataclass
class ProxyResult:
    """``V``, ``F`` of the proxy and the decimation's seconds."""

    V: np.ndarray
    F: np.ndarray
    seconds: float


def decimate(V, F, vertices: int) -> ProxyResult:
    """Quadric edge collapse of ``(V, F)`` to about ``vertices`` vertices (within a few %);
    the mesh itself when it has no more than that."""
    import time

    V, F = check_mesh(V, F)
    if int(vertices) != vertices or vertices < 16:
        raise InvalidMeshError(f"vertices must be an integer >= 16; got {vertices!r}")
    t = time.perf_counter()
    if len(V) <= vertices:
        return ProxyResult(V, F, 0.0)
    fs = lazy_import("fast_simplification", "the proxy of a large scan")
    # faces ~ 2 × vertices on a closed or nearly closed surface; ask for the faces that give it
    target = 1.0 - min(1.0, 2.0 * vertices / max(len(F), 1))
    # the simplifier works in float32: centred first, so a scan far from the origin (millimetres,
    # metres away) keeps its precision
    c = 0.5 * (V.min(0) + V.max(0))
    # agg 9 (default 7): fewer passes, the same deviation from the scan (measured on the 2M bust:
    # max 9.7e-4 vs 9.2e-4 of the diagonal, p99 5.3e-4 for both; 8.4 s vs 11.8 s)
    V1, F1 = fs.simplify((V - c).astype(np.float32), F.astype(np.int32), target_reduction=float(np.clip(target, 0.0, 0.999)),
                         agg=9)
    V1 = np.asarray(V1, np.float64) + c
    F1 = np.asarray(F1, np.int64)
    if len(F1) == 0:
        raise InvalidMeshError("decimation left no faces")
    return ProxyResult(V1, F1, time.perf_counter() - t)
