"""Robust repair of messy scans to a topological disk.

Each step is a function returning a :class:`StepResult` (new arrays, maps back to the
input, a list of changes); :func:`make_disk` chains them.
"""

from .clean import clean, make_manifold, merge_vertices, remove_degenerate_faces, remove_unreferenced_vertices
from .components import keep_components
from .disk import OPEN_MODES, DiskResult, RepairOptions, make_disk
from .handles import remove_handles
from .holes import fill_holes, fill_loops
from .opening import open_at_plane, open_with_cap
from .remesh import remesh
from .step import StepResult

from .points import PointSurface, load_points, surface_from_points
from .proxy import ProxyResult, decimate

__all__ = [
    "DiskResult",
    "OPEN_MODES",
    "ProxyResult",
    "RepairOptions",
    "StepResult",
    "clean",
    "decimate",
    "fill_holes",
    "fill_loops",
    "keep_components",
    "make_disk",
    "make_manifold",
    "merge_vertices",
    "open_at_plane",
    "open_with_cap",
    "remesh",
    "remove_degenerate_faces",
    "remove_handles",
    "remove_unreferenced_vertices",
    "PointSurface",
    "load_points",
    "surface_from_points",
]
