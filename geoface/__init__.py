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
from ._lazy import lazy_exports
from .tol import tol

__version__ = "0.2.0"


#: the main verbs, imported on first use: name -> the module that defines it
_VERBS = {
    "Mesh": "geoface.mesh", "load_mesh": "geoface.mesh", "save_mesh": "geoface.mesh",
    "make_disk": "geoface.repair", "surface_from_points": "geoface.repair",
    "ricci_flow_rectangle": "geoface.param.ricci", "RicciFlowSolver": "geoface.param.ricci",
    "measure_preserving_map": "geoface.param.measure", "MeasurePreservingSolver": "geoface.param.measure",
    "geometry_image": "geoface.gimage", "load_gimage": "geoface.gimage", "save_gimage": "geoface.gimage",
    "reconstruct": "geoface.gimage",
    "convert": "geoface.pipeline", "ConvertOptions": "geoface.pipeline",
}
_SUBPACKAGES = {"mesh", "repair", "synth", "param", "gimage", "uvmap", "learn", "splat", "cli", "pipeline"}


_verb, _verbs_dir, _VERB_NAMES = lazy_exports("geoface", _VERBS)


def __getattr__(name):  # lazy subpackages (geoface.mesh, ...) and verbs (geoface.convert, ...)
    if name in _SUBPACKAGES:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    return _verb(name)


def __dir__():
    return sorted(set(globals()) | set(_verbs_dir()) | _SUBPACKAGES)


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
    *_VERB_NAMES,
]
