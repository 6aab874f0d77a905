"""What the visual checks (:mod:`geoface.viz`) and the web viewer draw, as plain arrays (no
pyvista): the mesh, UVs, colours and texture of a Mesh, a SynthHead or a ``(V, F)`` pair;
per-corner UVs split into per-vertex ones; colours and textures in 8 bits; a geometry image's
tiles; distances from points to a surface."""

from __future__ import annotations

import numpy as np

from .errors import InvalidMeshError


def check_VF(V, F):
    """:func:`geoface.mesh.core.check_mesh`, imported on first use."""
    from .mesh.core import check_mesh

    return check_mesh(V, F)


def unpack_mesh(mesh_or_VF):
    """(V, F, UV, FUV, colors, texture) from a Mesh, a SynthHead-like object or a (V, F) tuple."""
    if isinstance(mesh_or_VF, (tuple, list)):
        if len(mesh_or_VF) != 2:
            raise InvalidMeshError("pass a Mesh or a (V, F) pair")
        return mesh_or_VF[0], mesh_or_VF[1], None, None, None, None
    m = mesh_or_VF
    if not hasattr(m, "V") or not hasattr(m, "F"):
        raise InvalidMeshError(f"expected a Mesh or a (V, F) pair; got {type(m).__name__}")
    UV, FUV = getattr(m, "UV", None), getattr(m, "FUV", None)
    if UV is not None and FUV is None and len(UV) == len(m.V):
        FUV = m.F  # per-vertex UVs (e.g. SynthHead)
    return m.V, m.F, UV, FUV, getattr(m, "colors", None), getattr(m, "texture", None)


def split_corner_uvs(V, F, UV, FUV):
    """Split vertices so that per-corner UVs become per-vertex (needed for VTK texturing).

    Returns ``V2 (k, 3)``, ``F2 (m, 3)``, ``uv2 (k, 2)`` and ``vmap (k,)`` (new vertex → old vertex);
    one new vertex per distinct (vertex, UV index) pair.
    """
    V, F = check_VF(V, F)
    FUV = np.asarray(FUV, np.int64)
    pairs = np.stack([F.ravel(), FUV.ravel()], axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    vmap = uniq[:, 0]
    return V[vmap], inv.reshape(F.shape).astype(np.int64), np.asarray(UV, np.float64)[uniq[:, 1]], vmap


def to_uint8_rgb(colors: np.ndarray, n: int, what: str) -> np.ndarray:
    C = np.asarray(colors)
    if C.ndim == 1 and C.shape[0] == 3:
        C = np.broadcast_to(C, (n, 3))
    if C.ndim != 2 or C.shape[0] != n or C.shape[1] not in (3, 4):
        raise InvalidMeshError(f"{what} must have shape ({n}, 3) or ({n}, 4); got {C.shape}")
    C = C[:, :3]
    if C.dtype != np.uint8:
        C = np.clip(np.round(np.asarray(C, np.float64) * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(C)


def texture_uint8(texture) -> np.ndarray:
    T = np.asarray(texture)
    if T.ndim == 2:
        T = np.repeat(T[..., None], 3, axis=2)
    if T.ndim != 3 or T.shape[2] not in (1, 3, 4):
        raise InvalidMeshError(f"texture must be an (h, w, 3) image; got shape {T.shape}")
    if T.shape[2] == 1:
        T = np.repeat(T, 3, axis=2)
    if T.dtype == np.uint16:
        T = (T // 257).astype(np.uint8)
    elif T.dtype != np.uint8:
        T = np.clip(np.round(np.asarray(T, np.float64) * 255), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(T[..., :3])


def gimage_tiles(gi) -> list[tuple[str, np.ndarray]]:
    """(name, (N, N, 3) uint8) tiles of a GeometryImage's modalities and mask."""
    tiles = []
    for name in ("position", "normal", "texture"):
        if gi.has(name):
            t = np.clip(gi.modality(name).transpose(1, 2, 0), 0, 1)
            tiles.append((name, np.round(t * 255).astype(np.uint8)))
    m = np.asarray(gi.mask, bool)
    tiles.append(("mask", np.repeat((m * 255).astype(np.uint8)[..., None], 3, axis=2)))
    return tiles


def distances(A_V, B_V, B_F):
    """Distance from each point of A_V to the surface (V, F) B (closest point on triangles)."""
    try:
        import igl  # noqa: F401

        d2, _, _ = igl.point_mesh_squared_distance(np.asarray(A_V, np.float64), np.asarray(B_V, np.float64),
                                                   np.asarray(B_F, np.int64))
        return np.sqrt(np.maximum(d2, 0.0))
    except Exception:  # igl missing or API mismatch: vertex-to-vertex distance
        from scipy.spatial import cKDTree

        d, _ = cKDTree(np.asarray(B_V, np.float64)).query(np.asarray(A_V, np.float64))
        return d
