"""Ground-truth renders of coloured meshes: a small vectorised numpy z-buffer.

For every pixel centre (``(j + 0.5, i + 0.5)``, the :class:`~geoface.camera.Camera`
convention) the nearest triangle is found by enumerating the pixels of each triangle's
bounding box (:func:`geoface.gimage.raster.bbox_pixels`, shared with the UV rasterizer and the
projection z-buffer) and keeping, per pixel, the candidate with the smallest camera depth.
Attributes are interpolated perspective-correctly: with screen-space barycentrics ``b_i`` and
vertex depths ``z_i``, ``w_i = b_i / z_i``, ``z = 1 / Σ w_i`` and the attribute weights are
``w_i z``. No Python loop runs over faces or pixels (only over chunks of candidates).

Colours are albedo (unlit) by default, which is what splats fitted to the renders should
reproduce; ``shading="headlight"`` adds a simple Lambert term for previews.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from geoface.gimage.raster import bbox_pixels, sample_texture
from geoface.camera import Camera
from geoface.nn.errors import RenderError

__all__ = ["MeshRender", "rasterize_mesh", "render_mesh"]

SHADINGS = ("none", "headlight")


@dataclass(frozen=True)
class MeshRender:
    """``rgb (H, W, 3)`` float64 in [0, 1] (composited over the background), ``alpha (H, W)``
    coverage in [0, 1] (0/1 without supersampling), ``depth (H, W)`` camera z of the nearest
    surface (0 where empty; the mean over covered samples with supersampling), ``face (H, W)``
    int64 nearest triangle (−1 where empty; the first sub-sample's with supersampling)."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    face: np.ndarray


def rasterize_mesh(V, F, camera: Camera, *, near: float = 1e-6, chunk: int = 2_000_000):
    """Nearest triangle per pixel centre.

    Parameters
    ----------
    V : (n, 3) float64 world positions; F : (m, 3) int64 triangles
    camera : Camera
    near : triangles with a vertex at camera depth ``<= near`` are skipped

    Returns
    -------
    face : (H, W) int64, −1 where no triangle covers the pixel centre
    bary : (H, W, 3) float64 perspective-correct barycentric weights (zeros where empty)
    depth : (H, W) float64 camera-space z (inf where empty)
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise RenderError(f"V must have shape (n, 3); got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise RenderError(f"F must have shape (m, 3); got {F.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise RenderError(f"F indexes vertices out of range [0, {len(V)})")
    if not isinstance(camera, Camera):
        raise RenderError(f"camera must be a geoface.camera.Camera; got {type(camera).__name__}")
    H, W = camera.height, camera.width
    uv, z = camera.project(V)
    x, y, zf = uv[F, 0] - 0.5, uv[F, 1] - 0.5, z[F]  # bbox_pixels: pixel centres at integers
    det = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    j0 = np.clip(np.ceil(x.min(1)), 0, W - 1).astype(np.int64)
    j1 = np.clip(np.floor(x.max(1)), 0, W - 1).astype(np.int64)
    i0 = np.clip(np.ceil(y.min(1)), 0, H - 1).astype(np.int64)
    i1 = np.clip(np.floor(y.max(1)), 0, H - 1).astype(np.int64)
    on = ((det != 0) & (zf.min(1) > near) & (x.max(1) >= 0) & (x.min(1) <= W - 1)
          & (y.max(1) >= 0) & (y.min(1) <= H - 1))
    nj = np.maximum(j1 - j0 + 1, 1)
    count = np.where(on, nj * np.maximum(i1 - i0 + 1, 0), 0)
    zbuf = np.full(H * W, np.inf)
    face = np.full(H * W, -1, dtype=np.int64)
    bary = np.zeros((H * W, 3))
    for tt, ii, jj, b0, b1, b2 in bbox_pixels(x, y, det, j0, i0, nj, count, chunk):
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        tt, pix = tt[inside], ii[inside] * W + jj[inside]
        w = np.clip(np.stack([b0[inside], b1[inside], b2[inside]], 1), 0.0, None) / zf[tt]
        zc = 1.0 / w.sum(1)  # perspective-correct depth: 1/z is linear on screen
        order = np.lexsort((zc, pix))  # by pixel, nearest first
        first = np.ones(len(order), dtype=bool)
        first[1:] = pix[order[1:]] != pix[order[:-1]]
        k = order[first]
        win = zc[k] < zbuf[pix[k]]  # nearer than what earlier chunks left
        k = k[win]
        zbuf[pix[k]] = zc[k]
        face[pix[k]] = tt[k]
        bary[pix[k]] = w[k] * zc[k, None]
    return face.reshape(H, W), bary.reshape(H, W, 3), zbuf.reshape(H, W)


def _scaled(camera: Camera, s: int) -> Camera:
    return Camera(camera.fx * s, camera.fy * s, camera.cx * s, camera.cy * s,
                  camera.width * s, camera.height * s, camera.R, camera.t)


def render_mesh(V, F, camera: Camera, colors=None, *, uv=None, fuv=None, texture=None,
                background=(0.0, 0.0, 0.0), shading: Literal["none", "headlight"] = "none",
                ambient: float = 0.3, supersample: int = 1) -> MeshRender:
    """Render a mesh with per-vertex colours (or a UV texture) seen by ``camera``.

    Parameters
    ----------
    V : (n, 3) float64; F : (m, 3) int64
    camera : Camera
    colors : (n, 3) or (n, 4) float in [0, 1], per-vertex colours (alpha channel ignored)
    uv : (n, 2) per-vertex UVs, or (k, 2) with ``fuv`` (m, 3) indexing them per corner
    texture : (h, w, 3) image, row 0 = v 1 (uint8 → /255); used instead of ``colors``
    background : RGB in [0, 1] behind the mesh
    shading : "none" (albedo, default) or "headlight" (Lambert with a light at the camera,
        ``ambient + (1 − ambient)·|n·v|`` per face)
    supersample : render at ``s×`` the resolution and box-filter down (anti-aliased edges,
        fractional alpha)

    Returns
    -------
    MeshRender(rgb, alpha, depth, face)

    Examples
    --------
    >>> from geoface.splat import look_at
    >>> V = np.array([[-1.0, -1, 0], [1, -1, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> r = render_mesh(V, F, look_at([0, 0, 3], [0, 0, 0], width=32, height=32), np.ones((3, 3)))
    >>> r.rgb.shape, float(r.depth[16, 16])
    ((32, 32, 3), 3.0)
    """
    if shading not in SHADINGS:
        raise RenderError(f"shading must be one of {SHADINGS}; got {shading!r}")
    s = int(supersample)
    if s < 1:
        raise RenderError(f"supersample must be >= 1; got {supersample!r}")
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    bg = np.asarray(background, dtype=np.float64).reshape(-1)
    if bg.shape != (3,):
        raise RenderError(f"background must be an RGB triple; got shape {bg.shape}")
    cam = _scaled(camera, s) if s > 1 else camera
    face, bary, depth = rasterize_mesh(V, F, cam)
    hit = face >= 0
    f = face[hit]
    b = bary[hit]
    if texture is not None:
        if uv is None:
            raise RenderError("texture needs uv (per-vertex, or with fuv per corner)")
        UV = np.asarray(uv, dtype=np.float64)
        FUV = F if fuv is None else np.asarray(fuv, dtype=np.int64)
        if UV.ndim != 2 or UV.shape[1] != 2 or FUV.shape != F.shape:
            raise RenderError(f"uv must have shape (k, 2) and fuv the shape of F; got {UV.shape}, {FUV.shape}")
        tex = np.asarray(texture)
        scale = 255.0 if tex.dtype == np.uint8 else 1.0
        col = sample_texture(tex, (UV[FUV[f]] * b[:, :, None]).sum(1))[:, :3] / scale
    elif colors is not None:
        C = np.asarray(colors, dtype=np.float64)
        if C.ndim != 2 or C.shape[0] != len(V) or C.shape[1] not in (3, 4):
            raise RenderError(f"colors must have shape ({len(V)}, 3) or ({len(V)}, 4); got {C.shape}")
        col = (C[F[f], :3] * b[:, :, None]).sum(1)
    else:
        col = np.full((len(f), 3), 0.8)
    if shading == "headlight":
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[f]
        P = (V[F[f]] * b[:, :, None]).sum(1)
        view = cam.center - P
        cos = np.abs((fn * view).sum(1)) / np.maximum(
            np.linalg.norm(fn, axis=1) * np.linalg.norm(view, axis=1), 1e-300)
        col = col * (ambient + (1.0 - ambient) * cos)[:, None]
    H, W = cam.height, cam.width
    rgb = np.broadcast_to(bg, (H, W, 3)).copy()
    rgb[hit] = np.clip(col, 0.0, 1.0)
    alpha = hit.astype(np.float64)
    zmap = np.where(hit, depth, 0.0)
    if s > 1:
        h, w = camera.height, camera.width
        pool = lambda a: a.reshape(h, s, w, s, *a.shape[2:]).mean((1, 3))  # noqa: E731
        rgb, cover, zsum = pool(rgb), pool(alpha), pool(zmap)
        zmap = np.where(cover > 0, zsum / np.where(cover > 0, cover, 1.0), 0.0)
        alpha, face = cover, face[::s, ::s]
    return MeshRender(rgb, alpha, zmap, face)
