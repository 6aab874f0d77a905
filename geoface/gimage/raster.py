"""Exact, vectorised rasterization of a triangle mesh through its UVs onto an N×N grid.

Two pixel grids (``align_corners``, as in PyTorch):

* ``align_corners=True`` — geometry images: pixel ``(i, j)`` samples UV
  ``(j / (N - 1), 1 - i / (N - 1))``.  The outermost rows and columns lie on the square's
  edges, where a parameterization puts the mesh boundary, so the boundary is sampled and a
  reconstruction keeps it.
* ``align_corners=False`` — texture images: pixel ``(i, j)``'s centre is UV
  ``((j + 0.5) / N, 1 - (i + 0.5) / N)``, the convention of renderers and UV atlases.

Row 0 is v = 1 in both.  Every pixel centre inside (or on the edge of) a UV triangle gets that triangle's index and
its exact barycentric coordinates; attributes are then interpolated linearly.  Triangles are
processed in chunks, each enumerating the pixel centres of its bounding box, so memory stays
bounded at N = 2048 and beyond.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidGeometryImageError
from ..mesh.raster import bbox_pixels, rasterize_mesh  # noqa: F401  (public here too)
from ..mesh.core import check_mesh

__all__ = ["rasterize_faces", "rasterize_mesh", "bbox_pixels", "interpolate", "interpolate_corners", "sample_texture", "uv_to_pixel",
           "pixel_grid_uv", "MAX_RES"]

MAX_RES = 8192


def _check_res(N: int) -> int:
    if int(N) != N or not (2 <= N <= MAX_RES):
        raise InvalidGeometryImageError(f"resolution must be an integer in [2, {MAX_RES}]; got {N!r}")
    return int(N)


def uv_to_pixel(uv: np.ndarray, N: int, align_corners: bool) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel coordinates ``(x, y)`` = (column, row) of UVs, pixel centres at
    integers (see module docs for the two grids)."""
    uv = np.asarray(uv, np.float64)
    if align_corners:
        return uv[..., 0] * (N - 1), (1.0 - uv[..., 1]) * (N - 1)
    return uv[..., 0] * N - 0.5, (1.0 - uv[..., 1]) * N - 0.5


def pixel_grid_uv(N: int, align_corners: bool) -> np.ndarray:
    """``(N, N, 2)`` UV sampled by every pixel (see module docs for the two grids)."""
    j, i = np.meshgrid(np.arange(N, dtype=np.float64), np.arange(N, dtype=np.float64))
    if align_corners:
        return np.stack([j / (N - 1), 1.0 - i / (N - 1)], -1)
    return np.stack([(j + 0.5) / N, 1.0 - (i + 0.5) / N], -1)


def rasterize_faces(F: np.ndarray, uv: np.ndarray, N: int, *, align_corners: bool = False,
                    chunk: int = 4_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Which triangle covers each pixel's sample point, and where.

    ``align_corners``: the pixel grid (module docs): True for geometry images (the square's
    edges sampled), False for texture images (pixel centres).  Returns ``face (N, N)
    int64`` (-1 where no triangle covers the pixel) and ``bary (N, N, 3) float64``
    barycentric coordinates (zeros where uncovered).  Pixels on a shared edge go to one of
    the triangles.
    """
    N = _check_res(N)
    F = np.asarray(F, np.int64)
    uv = np.asarray(uv, np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or not np.isfinite(uv).all():
        raise InvalidGeometryImageError("uv must be a finite (n, 2) array")
    # pixel coordinates: x = column, y = row, both continuous with centres at integers
    X, Y = uv_to_pixel(uv, N, align_corners)
    x = X[F]
    y = Y[F]
    det = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    j0 = np.clip(np.ceil(x.min(1) - 1e-9), 0, N - 1).astype(np.int64)
    j1 = np.clip(np.floor(x.max(1) + 1e-9), 0, N - 1).astype(np.int64)
    i0 = np.clip(np.ceil(y.min(1) - 1e-9), 0, N - 1).astype(np.int64)
    i1 = np.clip(np.floor(y.max(1) + 1e-9), 0, N - 1).astype(np.int64)
    nj = np.maximum(j1 - j0 + 1, 0)
    ni = np.maximum(i1 - i0 + 1, 0)
    count = np.where((det != 0) & (x.max(1) >= -1) & (x.min(1) <= N) & (y.max(1) >= -1) & (y.min(1) <= N), nj * ni, 0)
    face = np.full(N * N, -1, np.int64)
    bary = np.zeros((N * N, 3))
    for tt, ii, jj, b0, b1, b2 in bbox_pixels(x, y, det, j0, i0, nj, count, chunk):
        eps = -1e-10
        inside = (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
        pix = ii[inside] * N + jj[inside]
        face[pix] = tt[inside]
        bb = np.clip(np.column_stack([b0[inside], b1[inside], b2[inside]]), 0.0, 1.0)
        bary[pix] = bb / bb.sum(1, keepdims=True)
    return face.reshape(N, N), bary.reshape(N, N, 3)


def interpolate(face: np.ndarray, bary: np.ndarray, F: np.ndarray, attr: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Per-vertex ``attr (n, k)`` at every pixel: ``(k, N, N)``; ``fill`` where uncovered."""
    attr = np.asarray(attr, np.float64)
    if attr.ndim == 1:
        attr = attr[:, None]
    N = face.shape[0]
    out = np.full((N * N, attr.shape[1]), fill, np.float64)
    f = face.ravel()
    ok = f >= 0
    b = bary.reshape(-1, 3)[ok]
    tri = F[f[ok]]
    out[ok] = (attr[tri] * b[:, :, None]).sum(1)
    return out.T.reshape(attr.shape[1], N, N)


def interpolate_corners(face: np.ndarray, bary: np.ndarray, corner_attr: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Per-face-corner ``corner_attr (m, 3, k)`` at every pixel: ``(k, N, N)``."""
    corner_attr = np.asarray(corner_attr, np.float64)
    N = face.shape[0]
    k = corner_attr.shape[2]
    out = np.full((N * N, k), fill, np.float64)
    f = face.ravel()
    ok = f >= 0
    b = bary.reshape(-1, 3)[ok]
    out[ok] = (corner_attr[f[ok]] * b[:, :, None]).sum(1)
    return out.T.reshape(k, N, N)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an ``(h, w, c)`` image (row 0 = v 1) at ``uv (..., 2)``; values in
    the image's units (uint8 images give 0..255 floats).  UVs outside [0, 1] wrap (repeat);
    lookups clamp at the image's edges (u = 0 does not blend in the far column)."""
    T = np.asarray(texture)
    if T.ndim == 2:
        T = T[:, :, None]
    h, w = T.shape[:2]
    uu, vv = uv[..., 0], uv[..., 1]
    uu = np.where((uu >= 0) & (uu <= 1), uu, np.mod(uu, 1.0))
    vv = np.where((vv >= 0) & (vv <= 1), vv, np.mod(vv, 1.0))
    u = uu * w - 0.5
    v = (1.0 - vv) * h - 0.5
    x0 = np.floor(u).astype(np.int64)
    y0 = np.floor(v).astype(np.int64)
    fx = (u - x0)[..., None]
    fy = (v - y0)[..., None]
    x0c, x1c = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    y0c, y1c = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    Tf = T.astype(np.float64)
    top = Tf[y0c, x0c] * (1 - fx) + Tf[y0c, x1c] * fx
    bot = Tf[y1c, x0c] * (1 - fx) + Tf[y1c, x1c] * fx
    return top * (1 - fy) + bot * fy
