"""Ground-truth renders of coloured meshes: a small vectorised numpy z-buffer.

The nearest triangle per pixel centre and its perspective-correct barycentrics come from
:func:`geoface.gimage.raster.rasterize_mesh`, the library's one camera-space z-buffer (the photo
projection of :mod:`geoface.uvmap` uses it for visibility); this module interpolates colours or
a texture with those weights, supersamples and shades.

Colours are albedo (unlit) by default, which is what splats fitted to the renders should
reproduce; ``shading="headlight"`` adds a simple Lambert term for previews.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from geoface.gimage.raster import rasterize_mesh, sample_texture
from geoface.camera import Camera
from geoface.errors import RenderError

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
