"""Project photographs onto a mesh's UV texture.

Camera convention (OpenCV): a world point ``X`` maps to camera coordinates ``Xc = R X + t``
(``R`` 3×3 rotation, ``t`` 3-vector, or one 4×4 world→camera matrix), the camera looks down
``+z``, ``x`` points right and ``y`` down; the pixel is ``(u, v) = (K Xc)[:2] / z``, with pixel
``(row v, column u)`` centres at integer coordinates (``u = 0`` is the centre of column 0).

For every texel of the target's UV layout (``T × T``) the 3D point and interpolated normal are
rasterized; each view projects the point, tests visibility against a depth buffer of the mesh
rendered from that camera (vectorised numpy z-buffer, tolerance ``depth_tol``), weights it by
``max(0, cos θ)^power`` (θ between normal and the direction to the camera), and samples the
photo bilinearly.  Views are blended by weight; texels no view sees keep the default texture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..errors import GeofaceError
from ..gimage.raster import bbox_pixels
from ..mesh.core import bbox_diagonal
from ..mesh.io import Mesh
from .bake import texel_geometry

__all__ = ["Camera", "depth_buffer", "project_views", "ProjectionResult"]


def depth_buffer(V, F, camera: Camera, shape: tuple[int, int], *, chunk: int = 2_000_000) -> np.ndarray:
    """Camera-space depth ``z`` of the nearest surface at every pixel centre, ``(H, W)`` (inf where
    empty).  Triangles with a vertex behind the near plane are skipped.  Depth is interpolated
    perspective-correctly (1/z is linear in the image)."""
    H, W = int(shape[0]), int(shape[1])
    uv, z = camera.project(np.asarray(V, np.float64))
    F = np.asarray(F, np.int64)
    near = 1e-9 * bbox_diagonal(np.asarray(V))
    x, y, zf = uv[F, 0], uv[F, 1], z[F]
    det = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    j0 = np.clip(np.ceil(x.min(1)), 0, W - 1).astype(np.int64)
    j1 = np.clip(np.floor(x.max(1)), 0, W - 1).astype(np.int64)
    i0 = np.clip(np.ceil(y.min(1)), 0, H - 1).astype(np.int64)
    i1 = np.clip(np.floor(y.max(1)), 0, H - 1).astype(np.int64)
    on = (det != 0) & (zf.min(1) > near) & (x.max(1) >= 0) & (x.min(1) <= W - 1) & (y.max(1) >= 0) & (y.min(1) <= H - 1)
    count = np.where(on, np.maximum(j1 - j0 + 1, 0) * np.maximum(i1 - i0 + 1, 0), 0)
    nj = np.maximum(j1 - j0 + 1, 1)
    zbuf = np.full(H * W, np.inf)
    for tt, ii, jj, b0, b1, b2 in bbox_pixels(x, y, det, j0, i0, nj, count, chunk):
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        za = zf[tt[inside]]
        inv = b0[inside] / za[:, 0] + b1[inside] / za[:, 1] + b2[inside] / za[:, 2]
        np.minimum.at(zbuf, ii[inside] * W + jj[inside], 1.0 / inv)
    return zbuf.reshape(H, W)


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample ``img (H, W, C)`` at pixel coordinates ``uv (k, 2)`` (centres at integers, clamped)."""
    H, W = img.shape[:2]
    u = np.clip(uv[:, 0], 0, W - 1)
    v = np.clip(uv[:, 1], 0, H - 1)
    x0 = np.minimum(np.floor(u).astype(np.int64), W - 2 if W > 1 else 0)
    y0 = np.minimum(np.floor(v).astype(np.int64), H - 2 if H > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    fx, fy = (u - x0)[:, None], (v - y0)[:, None]
    return (img[y0, x0] * (1 - fx) + img[y0, x1] * fx) * (1 - fy) + (img[y1, x0] * (1 - fx) + img[y1, x1] * fx) * fy


@dataclass(frozen=True)
class ProjectionResult:
    """``texture (T, T, 3)`` float64 in the images' units; ``weight (T, T)`` summed view weights
    (0 = no view sees the texel; it holds the default); ``per_view (n_views, T, T)`` weights."""

    texture: np.ndarray
    weight: np.ndarray
    per_view: np.ndarray


def _as_image(img, i) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or min(a.shape[:2]) < 2:
        raise GeofaceError(f"images[{i}] must be an (H, W, 3) image; got {np.asarray(img).shape}")
    a = a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
    if not np.isfinite(a).all():
        raise GeofaceError(f"images[{i}] has NaN or infinite values")
    return np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a[:, :, :3]


def project_views(mesh: Mesh, images, cameras, size: int = 1024, *, power: float = 2.0,
                  depth_tol: float = 1e-3, default=(0.5, 0.5, 0.5)) -> ProjectionResult:
    """Write the colours of one or more photos into ``mesh``'s UV texture (``size × size``).

    Parameters
    ----------
    mesh : Mesh with ``UV``/``FUV`` (the texture layout; row 0 = v 1)
    images : one ``(H, W, 3)`` image (uint8 → /255, float as is) or a list, one per camera
    cameras : a :class:`Camera` or a list of them (OpenCV convention; see the module docstring)
    power : exponent ``p`` of the view-angle weight ``max(0, cos θ)^p``
    depth_tol : visibility tolerance, a fraction of the mesh's bounding-box diagonal: a texel is
        visible when its depth is within this of the depth buffer's
    default : an RGB constant or a ``(size, size, 3)`` texture for texels no view sees

    Returns
    -------
    ProjectionResult(texture, weight, per_view)

    Examples
    --------
    >>> cam = Camera.from_K(K, R, t)                             # doctest: +SKIP
    >>> res = project_views(mesh, photo, cam, 1024)             # doctest: +SKIP
    >>> seen = res.weight > 0                                    # doctest: +SKIP
    """
    if isinstance(cameras, Camera):
        cameras = [cameras]
    if not isinstance(images, (list, tuple)):
        images = [images]
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise GeofaceError("cameras must be a Camera or a non-empty list of Camera objects")
    if len(images) != len(cameras):
        raise GeofaceError(f"need one image per camera; got {len(images)} images and {len(cameras)} cameras")
    imgs = [_as_image(im, i) for i, im in enumerate(images)]
    if not (np.isfinite(power) and power >= 0):
        raise GeofaceError(f"power must be a finite number >= 0; got {power!r}")
    if not (np.isfinite(depth_tol) and depth_tol > 0):
        raise GeofaceError(f"depth_tol must be a finite number > 0; got {depth_tol!r}")
    P, Nrm, mask = texel_geometry(mesh, size)
    T = int(size)
    dflt = np.asarray(default, np.float64)
    if dflt.shape == (3,):
        dflt = np.broadcast_to(dflt, (T, T, 3))
    elif dflt.shape != (T, T, 3):
        raise GeofaceError(f"default must be an RGB triple or a ({T}, {T}, 3) texture; got {dflt.shape}")
    if not np.isfinite(dflt).all():
        raise GeofaceError("default has NaN or infinite values")
    tol = depth_tol * bbox_diagonal(mesh.V)
    idx = np.flatnonzero(mask.ravel())
    X, n = P.reshape(-1, 3)[idx], Nrm.reshape(-1, 3)[idx]
    acc = np.zeros((len(idx), 3))
    wsum = np.zeros(len(idx))
    per_view = np.zeros((len(cameras), T * T))
    for k, (cam, img) in enumerate(zip(cameras, imgs)):
        H, W = img.shape[:2]
        zbuf = depth_buffer(mesh.V, mesh.F, cam, (H, W))
        uv, z = cam.project(X)
        inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
        # nearest depth sample and its neighbours: visible when no pixel around it is much nearer
        col = np.clip(np.round(uv[:, 0]).astype(np.int64), 0, W - 1)
        row = np.clip(np.round(uv[:, 1]).astype(np.int64), 0, H - 1)
        zref = zbuf[row, col]
        visible = inside & np.isfinite(zref) & (z <= zref + tol)
        view = cam.center - X
        cos = (n * view).sum(1) / np.maximum(np.linalg.norm(view, axis=1), 1e-300)
        w = np.where(visible, np.maximum(cos, 0.0) ** power, 0.0) * (cos > 0)
        sel = w > 0
        acc[sel] += w[sel, None] * _bilinear(img, uv[sel])
        wsum += w
        per_view[k, idx] = w
    tex = np.array(dflt, np.float64, copy=True).reshape(-1, 3)
    seen = wsum > 0
    tex[idx[seen]] = acc[seen] / wsum[seen, None]
    weight = np.zeros(T * T)
    weight[idx] = wsum
    return ProjectionResult(tex.reshape(T, T, 3), weight.reshape(T, T), per_view.reshape(-1, T, T))
