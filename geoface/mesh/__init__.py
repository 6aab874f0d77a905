"""Mesh core: plain arrays, file IO through trimesh, the topology report, and which way a mesh
faces.  ``load_mesh``, ``save_mesh`` and ``Mesh`` (file IO) and ``mesh_frame`` are imported on
first use, so ``import geoface.mesh`` does not load trimesh.

>>> from geoface.mesh import load_mesh, topology_report   # doctest: +SKIP
>>> m = load_mesh("scan.obj"); print(topology_report(m.V, m.F).format())   # doctest: +SKIP
"""

from .core import (
    EdgeTopology,
    bbox_diagonal,
    boundary_loops,
    check_mesh,
    degenerate_faces,
    duplicate_faces,
    edge_topology,
    face_areas,
    face_components,
    face_normals,
    loop_length,
    remove_unreferenced,
    signed_volume,
    vertex_areas,
    vertex_normals,
)
from .orient import solve_orientation
from .topology import TopologyReport, topology_report

from .._lazy import lazy_exports

# file IO (trimesh) and the frame search are imported on first use
__getattr__, _lazy_dir, _LAZY_NAMES = lazy_exports("geoface.mesh", {
    "Mesh": "io", "load_mesh": "io", "save_mesh": "io",
    "mesh_frame": "frame", "MeshFrame": "frame", "parse_up": "frame", "rasterize_mesh": "raster",
})


def __dir__():
    return sorted(set(__all__))


__all__ = [
    *_LAZY_NAMES,
    "EdgeTopology",
    "TopologyReport",
    "bbox_diagonal",
    "boundary_loops",
    "check_mesh",
    "degenerate_faces",
    "duplicate_faces",
    "edge_topology",
    "face_areas",
    "face_components",
    "face_normals",
    "loop_length",
    "remove_unreferenced",
    "signed_volume",
    "solve_orientation",
    "topology_report",
    "vertex_areas",
    "vertex_normals",
]
