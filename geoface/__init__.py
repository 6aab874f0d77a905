"""geoface: geometry processing of head and face meshes, with neural add-ons.

Layers (DESIGN.md): ``mesh`` -> ``repair`` -> ``param`` -> ``gimage`` -> ``uvmap`` ->
``learn`` / ``splat``; ``synth`` makes analytic surfaces and procedural heads.
Heavy optional stacks are imported inside the functions that need them, so
``import geoface`` stays light.

>>> import geoface
>>> from geoface.synth import procedural_head
>>> head = procedural_head(n_vertices=2000, seed=0)
>>> result = geoface.repair.make_disk(head.V, head.F)
>>> result.report.is_disk
True
"""

from __future__ import annotations

from . import errors
from .errors import (
    GeofaceError,
    GeofaceWarning,
    InvalidGeometryImageError,
    InvalidMeshError,
    MeshFormatError,
    MeshTopologyError,
    MissingDependencyError,
    ParameterizationError,
)
from .tol import tol

__version__ = "0.2.0"


def __getattr__(name):  # lazy subpackages: geoface.mesh, geoface.repair, geoface.synth, ...
    import importlib

    if name in {"mesh", "repair", "synth", "param", "gimage", "uvmap", "learn", "splat", "cli", "pipeline"}:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'geoface' has no attribute {name!r}")


__all__ = [
    "GeofaceError",
    "GeofaceWarning",
    "InvalidGeometryImageError",
    "InvalidMeshError",
    "MeshFormatError",
    "MeshTopologyError",
    "MissingDependencyError",
    "ParameterizationError",
    "errors",
    "tol",
    "__version__",
]
