"""The :class:`Mesh` a file loads into (:mod:`geoface.mesh.io`): the geometric mesh ``V, F``
with the attributes that travel with it — UVs per face corner (``UV``, ``FUV``), per-vertex
colours, a texture image — validated on construction and carried over to a repaired mesh."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InvalidMeshError
from .core import check_mesh


def first_corner_uv(F: np.ndarray, FUV: np.ndarray, n_vertices: int) -> np.ndarray:
    """Per vertex, the UV index of the first face corner that uses it (-1 if none): one UV
    per vertex where seams give several."""
    vert_uv = np.full(n_vertices, -1, np.int64)
    vert_uv[F.ravel()[::-1]] = FUV.ravel()[::-1]
    return vert_uv


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh with the attributes that travel with it.

    Attributes
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    UV : (t, 2) float64 or None, texture coordinates
    FUV : (m, 3) int64 or None, per-corner indices into ``UV``
    colors : (n, 4) float64 in [0, 1] or None, per-vertex RGBA
    texture : (h, w, c) uint8 or None, texture image (row 0 = top, v = 1)
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    FUV: np.ndarray | None = None
    colors: np.ndarray | None = None
    texture: np.ndarray | None = None

    def __post_init__(self):
        V, F = check_mesh(self.V, self.F)
        object.__setattr__(self, "V", V)
        object.__setattr__(self, "F", F)
        if (self.UV is None) != (self.FUV is None):
            raise InvalidMeshError("UV and FUV must be given together")
        if self.UV is not None:
            UV = np.asarray(self.UV, np.float64)
            FUV = np.asarray(self.FUV, np.int64)
            if UV.ndim != 2 or UV.shape[1] != 2:
                raise InvalidMeshError(f"UV must have shape (t, 2); got {UV.shape}")
            if FUV.shape != F.shape:
                raise InvalidMeshError(f"FUV must have the shape of F {F.shape}; got {FUV.shape}")
            if len(FUV) and (FUV.min() < 0 or FUV.max() >= len(UV)):
                raise InvalidMeshError("FUV indexes outside UV")
            if not np.isfinite(UV).all():
                raise InvalidMeshError("UV has NaN or infinite values")
            object.__setattr__(self, "UV", UV)
            object.__setattr__(self, "FUV", FUV)
        if self.colors is not None:
            C = np.asarray(self.colors, np.float64)
            if C.ndim != 2 or C.shape[0] != len(V) or C.shape[1] not in (3, 4):
                raise InvalidMeshError(f"colors must have shape (n, 3|4) with n={len(V)}; got {C.shape}")
            if C.shape[1] == 3:
                C = np.concatenate([C, np.ones((len(C), 1))], 1)
            object.__setattr__(self, "colors", np.clip(C, 0.0, 1.0))
        if self.texture is not None:
            T = np.asarray(self.texture)
            if T.ndim not in (2, 3) or T.dtype != np.uint8:
                raise InvalidMeshError(f"texture must be an (h, w[, c]) uint8 image; got {T.shape} {T.dtype}")

    @classmethod
    def from_vertex_uv(cls, V, F, UV=None, **kw) -> "Mesh":
        """Build from a per-vertex ``UV (n, 2)`` (``FUV = F``)."""
        if UV is None:
            return cls(V, F, **kw)
        return cls(V, F, UV=UV, FUV=np.asarray(F, np.int64), **kw)

    def with_geometry(self, V, F, vertex_map: np.ndarray, face_map: np.ndarray) -> "Mesh":
        """Carry attributes over to a repaired mesh.

        ``vertex_map[i]`` is the original vertex of new vertex ``i`` (or -1), ``face_map[f]``
        the original face of new face ``f`` (or -1).  UVs follow kept faces; new faces get
        the UV of their corners' original vertices where one exists, else (0, 0).
        """
        V, F = check_mesh(V, F)
        vertex_map = _index_map(vertex_map, len(V), len(self.V), "vertex_map", "vertices")
        face_map = _index_map(face_map, len(F), len(self.F), "face_map", "faces")
        colors = None
        if self.colors is not None:
            colors = np.zeros((len(V), 4))
            colors[:, 3] = 1.0
            ok = vertex_map >= 0
            colors[ok] = self.colors[vertex_map[ok]]
        UV = FUV = None
        if self.UV is not None:
            F = np.asarray(F, np.int64)
            FUV = np.zeros_like(F)
            kept = face_map >= 0
            FUV[kept] = self.FUV[face_map[kept]]
            vert_uv = first_corner_uv(self.F, self.FUV, len(self.V))
            newc = F[~kept]
            src = np.where(vertex_map[newc] >= 0, vert_uv[np.maximum(vertex_map[newc], 0)], -1)
            extra = len(self.UV)
            UV = np.concatenate([self.UV, np.zeros((1, 2))])
            FUV[~kept] = np.where(src >= 0, src, extra)
        return Mesh(V, F, UV=UV, FUV=FUV, colors=colors, texture=self.texture)


def _index_map(a, n: int, n_old: int, name: str, what: str) -> np.ndarray:
    """``a`` as an (n,) int64 map into ``n_old`` old elements (-1: new), or InvalidMeshError."""
    try:
        m = np.asarray(a)
    except (TypeError, ValueError):
        raise InvalidMeshError(f"{name} must be an integer array") from None
    if m.dtype.kind not in "iu" or m.shape != (n,):
        raise InvalidMeshError(f"{name} must be {n} integers (one per new {what[:-1]}); got {m.dtype} of shape {m.shape}")
    m = m.astype(np.int64)
    if len(m) and (m.min() < -1 or m.max() >= n_old):
        raise InvalidMeshError(f"{name} must hold old {what} in 0..{n_old - 1} or -1; got {m.min()}..{m.max()}")
    return m


def mesh_with(mesh: Mesh, **changes) -> Mesh:
    """``dataclasses.replace`` for :class:`Mesh` (re-validates)."""
    return replace(mesh, **changes)
