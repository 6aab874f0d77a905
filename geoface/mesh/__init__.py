"""Mesh core: plain arrays, file IO through trimesh, and the topology report."""

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

__all__ = [
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
