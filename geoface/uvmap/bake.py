"""Bake colours and normals from a high-resolution source mesh onto a target's pixels.

For every valid pixel of a geometry image, or every covered texel of a target mesh's UV
texture, the 3D point of that pixel is sent to the *closest point* on the source mesh
(libigl's AABB tree, ``igl.point_mesh_squared_distance``).  The source attribute is then
interpolated there with the exact barycentric coordinates of that closest point:

- per-vertex colours (``Mesh.colors``) → barycentric blend of the three vertex colours;
- a texture (``Mesh.UV``, ``Mesh.FUV``, ``Mesh.texture``) → barycentric blend of the corner
  UVs, then a bilinear lookup of the texture image;
- normals → barycentric blend of the source's area-weighted vertex normals, renormalised
  (object space).

Pixels whose closest source point is farther than ``max_distance`` stay empty (mask False).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np

from .._lazy import lazy_import
from ..errors import GeofaceError, InvalidGeometryImageError, InvalidMeshError
from ..gimage.image import MODALITIES, GeometryImage
from ..gimage.raster import interpolate, rasterize_faces, sample_texture
from ..mesh.core import vertex_normals
from ..mesh.io import Mesh

__all__ = ["SurfaceQuery", "closest_points", "sample_source", "bake_gimage", "bake_texture", "texel_geometry", "BakeResult"]

Attribute = Literal["color", "normal"]


class SurfaceQuery:
    """Closest points on one mesh ``(V, F)``, its AABB tree (libigl) built once for many queries
    (building it is most of the cost on a million-vertex mesh).

    >>> from geoface.synth import square_grid
    >>> V, F = square_grid(4)
    >>> dist, face, bary = SurfaceQuery(V, F)([[0.5, 0.5, 1.0]])
    >>> round(float(dist[0]), 6)
    1.0
    """

    def __init__(self, V, F):
        igl = lazy_import("igl", "closest-point queries")
        self.V = np.ascontiguousarray(V, np.float64)
        self.F = np.ascontiguousarray(F, np.int64)
        # an explicit AABB tree: same answer as igl.point_mesh_squared_distance, measurably faster
        # on 1e6-vertex sources (see bench/bench_bake.py)
        self._tree = igl.AABB()
        self._tree.init(self.V, self.F)

    def __call__(self, P) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(dist (k,), face (k,), bary (k, 3))`` of the closest surface point to each of ``P (k, 3)``."""
        P = np.ascontiguousarray(np.asarray(P, np.float64).reshape(-1, 3))
        if not np.isfinite(P).all():
            raise GeofaceError("query points P contain NaN or infinite values")
        if len(P) == 0:
            return np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3))
        d2, face, C = self._tree.squared_distance(self.V, self.F, P)
        face = np.asarray(face, np.int64).ravel()
        return np.sqrt(np.maximum(d2, 0.0)).ravel(), face, _barycentric(np.asarray(C, np.float64), self.V[self.F[face]])

    def points(self, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """The surface points ``(k, 3)`` at ``(face, bary)``."""
        return (self.V[self.F[np.asarray(face, np.int64)]] * np.asarray(bary, np.float64)[:, :, None]).sum(1)


def closest_points(P, V, F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point on the mesh ``(V, F)`` to every query point ``P (k, 3)`` (one
    :class:`SurfaceQuery`; build one yourself to query the same mesh many times).

    Returns
    -------
    dist : (k,) float64 Euclidean distance
    face : (k,) int64 index of the source face holding the closest point
    bary : (k, 3) float64 barycentric coordinates of the closest point in that face
    """
    P = np.asarray(P, np.float64).reshape(-1, 3)
    if len(P) == 0:  # no tree to build; SurfaceQuery checks the points
        return np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3))
    return SurfaceQuery(V, F)(P)


def _barycentric(C: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points ``C (k, 3)`` in triangles ``T (k, 3, 3)`` (clipped to the
    triangle, summing to 1; degenerate triangles give their first vertex)."""
    e1, e2, d = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0], C - T[:, 0]
    dot = lambda x, y: np.einsum("kd,kd->k", x, y)  # noqa: E731  (3x faster than (x * y).sum(1))
    a, b, c = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    p, q = dot(d, e1), dot(d, e2)
    den = a * c - b * b
    ok = den > 1e-300 * np.maximum(a * c, 1.0)
    den = np.where(ok, den, 1.0)
    b1 = np.where(ok, (c * p - b * q) / den, 0.0)
    b2 = np.where(ok, (a * q - b * p) / den, 0.0)
    B = np.clip(np.column_stack([1.0 - b1 - b2, b1, b2]), 0.0, None)
    return B / np.maximum(B.sum(1, keepdims=True), 1e-300)


def _check_source(source: Mesh, attribute: str) -> None:
    if not isinstance(source, Mesh):
        raise InvalidMeshError(f"source must be a geoface.mesh.io.Mesh; got {type(source).__name__}")
    if attribute not in ("color", "normal"):
        raise GeofaceError(f"attribute must be one of 'color', 'normal'; got {attribute!r}")
    if attribute == "color" and source.colors is None and (source.texture is None or source.UV is None):
        raise InvalidMeshError("source has no colours: it needs per-vertex colors or UV + FUV + texture")


def sample_source(source: Mesh, face: np.ndarray, bary: np.ndarray, attribute: Attribute = "color",
                  *, normals: np.ndarray | None = None) -> np.ndarray:
    """Source attribute at surface points given as ``(face (k,), bary (k, 3))``: ``(k, 3)`` float64.

    Colours are in [0, 1] (a uint8 texture is divided by 255); a texture wins over vertex
    colours.  Normals are unit, object space (``normals`` overrides the source's vertex normals).
    """
    _check_source(source, attribute)
    face = np.asarray(face, np.int64)
    bary = np.asarray(bary, np.float64)
    if attribute == "normal":
        Nv = vertex_normals(source.V, source.F) if normals is None else np.asarray(normals, np.float64)
        if Nv.shape != source.V.shape:
            raise InvalidMeshError(f"normals must have shape {source.V.shape}; got {Nv.shape}")
        n = (Nv[source.F[face]] * bary[:, :, None]).sum(1)
        L = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, L, out=np.zeros_like(n), where=L > 0)
    if source.texture is not None and source.UV is not None:
        uv = (source.UV[source.FUV[face]] * bary[:, :, None]).sum(1)
        rgb = sample_texture(source.texture, uv)
        if rgb.shape[-1] == 1:
            rgb = np.repeat(rgb, 3, axis=-1)
        return rgb[:, :3] / (255.0 if source.texture.dtype == np.uint8 else 1.0)
    return (source.colors[source.F[face], :3] * bary[:, :, None]).sum(1)


class BakeResult(tuple):
    """``(image (..., 3) float64, mask (...) bool)`` plus ``seconds`` (``query``, ``total``)."""

    seconds: dict

    def __new__(cls, image, mask, seconds):
        obj = super().__new__(cls, (image, mask))
        obj.seconds = seconds
        return obj


def _bake_points(P: np.ndarray, valid: np.ndarray, source: Mesh, attribute: str, max_distance) -> BakeResult:
    t0 = time.perf_counter()
    if max_distance is not None and not (np.isfinite(max_distance) and max_distance >= 0):
        raise GeofaceError(f"max_distance must be a finite number >= 0 or None; got {max_distance!r}")
    shape = valid.shape
    idx = np.flatnonzero(valid.ravel())
    out = np.zeros((valid.size, 3))
    dist, face, bary = closest_points(P.reshape(-1, 3)[idx], source.V, source.F)
    tq = time.perf_counter() - t0
    keep = np.ones(len(idx), bool) if max_distance is None else dist <= max_distance
    out[idx[keep]] = sample_source(source, face[keep], bary[keep], attribute)
    mask = np.zeros(valid.size, bool)
    mask[idx[keep]] = True
    return BakeResult(out.reshape(*shape, 3), mask.reshape(shape), {"query": tq, "total": time.perf_counter() - t0})


def bake_gimage(gi: GeometryImage, source: Mesh, *, attribute: Attribute = "color",
                max_distance: float | None = None, keep_unbaked: bool = False) -> GeometryImage:
    """Bake the source's colours (or normals) into a geometry image's ``texture`` (or ``normal``)
    modality; returns a new :class:`GeometryImage` (``gi`` is not modified).

    Parameters
    ----------
    gi : GeometryImage with position channels; ``gi.positions()`` at ``gi.mask`` are the queries
    source : Mesh with ``colors`` or ``UV``/``FUV``/``texture`` (for ``attribute="normal"``, any mesh)
    attribute : ``"color"`` → ``texture`` channels; ``"normal"`` → ``normal`` channels ((n + 1) / 2)
    max_distance : pixels whose closest source point is farther (mesh units) get value 0 and
        leave the output mask (unless ``keep_unbaked``)
    keep_unbaked : keep such pixels in ``mask`` (their baked value is 0) instead of dropping them

    Examples
    --------
    >>> gi2 = bake_gimage(gi, scan, max_distance=0.01)        # doctest: +SKIP
    >>> gi2.modality("texture").shape                          # doctest: +SKIP
    (3, 512, 512)
    """
    if not isinstance(gi, GeometryImage):
        raise InvalidGeometryImageError(f"gi must be a GeometryImage; got {type(gi).__name__}")
    _check_source(source, attribute)
    if not gi.has("position"):
        raise InvalidGeometryImageError("gi has no position channels to bake at")
    P = gi.positions()
    valid = np.asarray(gi.mask, bool) & np.isfinite(P).all(2)
    res = _bake_points(P, valid, source, attribute, max_distance)
    vals, ok = res
    name = "texture" if attribute == "color" else "normal"
    chan = vals.transpose(2, 0, 1) if attribute == "color" else (vals.transpose(2, 0, 1) + 1.0) * 0.5
    chan = np.clip(chan * ok, 0.0, 1.0).astype(np.float32)
    names = list(gi.meta["channels"])
    img = gi.image
    if gi.has(name):
        img = img.copy()
        for k, c in enumerate(MODALITIES[name]):
            img[names.index(c)] = chan[k]
    else:
        img = np.concatenate([img, chan], 0)
        names += list(MODALITIES[name])
    meta = dict(gi.meta, channels=names)
    meta["bake"] = {"attribute": attribute, "baked_fraction": float(ok.sum() / max(valid.sum(), 1)),
                    "max_distance": max_distance}
    mask = gi.mask.copy() if keep_unbaked else (np.asarray(gi.mask, bool) & ok)
    return GeometryImage(img, mask, meta)


def texel_geometry(target: Mesh, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rasterize ``target``'s UV layout at ``size × size``: per texel its 3D position
    ``(T, T, 3)``, unit interpolated vertex normal ``(T, T, 3)`` and coverage mask ``(T, T)``."""
    if not isinstance(target, Mesh):
        raise InvalidMeshError(f"target must be a geoface.mesh.io.Mesh; got {type(target).__name__}")
    if target.UV is None:
        raise InvalidMeshError("target has no UVs (UV and FUV) to bake into")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)):
        raise GeofaceError(f"size must be an integer; got {size!r}")
    face, bary = rasterize_faces(target.FUV, target.UV, int(size))
    mask = face >= 0
    P = interpolate(face, bary, target.F, target.V).transpose(1, 2, 0)
    n = interpolate(face, bary, target.F, vertex_normals(target.V, target.F)).transpose(1, 2, 0)
    L = np.linalg.norm(n, axis=2, keepdims=True)
    return P, np.divide(n, L, out=np.zeros_like(n), where=L > 0), mask


def bake_texture(target: Mesh, source: Mesh, size: int = 1024, *, attribute: Attribute = "color",
                 max_distance: float | None = None) -> BakeResult:
    """Bake the source's colours (or object-space normals) into a ``size × size`` UV texture of
    ``target`` (the target's ``UV``/``FUV`` layout; row 0 = v 1).

    Returns
    -------
    result : BakeResult
        ``(image, mask)``: ``image (size, size, 3)`` float64 (colours in [0, 1], or unit
        normals in [-1, 1]; zero where empty) and ``mask (size, size)`` bool of baked texels.
        Fill the rest with :func:`geoface.uvmap.inpaint`.  ``result.seconds`` times the
        closest-point queries and the whole bake.

    Examples
    --------
    >>> tex, mask = bake_texture(low, scan, 2048)                  # doctest: +SKIP
    >>> nmap, _ = bake_texture(low, scan, 2048, attribute="normal")  # doctest: +SKIP
    """
    _check_source(source, attribute)
    P, _, mask = texel_geometry(target, size)
    return _bake_points(P, mask, source, attribute, max_distance)
