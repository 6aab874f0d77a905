"""Project photographs onto a mesh's UV texture.

Camera convention (OpenCV): a world point ``X`` maps to camera coordinates ``Xc = R X + t``
(``R`` 3×3 rotation, ``t`` 3-vector, or one 4×4 world→camera matrix), the camera looks down
``+z``, ``x`` points right and ``y`` down; the pixel is ``(u, v) = (K Xc)[:2] / z``, and pixel
``(row i, column j)`` has its centre at ``(u, v) = (j + 0.5, i + 0.5)`` — the convention of
:class:`geoface.camera.Camera`, of :func:`geoface.nn.render_mesh` and of the face tracker's
landmarks, so a photo rendered or tracked by geoface projects back without a half-pixel shift.

For every texel of the target's UV layout (``T × T``) the 3D point and interpolated normal are
rasterized; each view projects the point, tests visibility against a depth buffer of the mesh
rendered from that camera (:func:`geoface.gimage.raster.rasterize_mesh`, tolerance ``depth_tol``), weights it by
``max(0, cos θ)^power`` (θ between normal and the direction to the camera), and samples the
photo bilinearly.  Views are blended by weight; texels no view sees keep the default texture.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..camera import Camera
from ..errors import GeofaceError
from ..gimage.raster import rasterize_mesh
from ..mesh.core import bbox_diagonal
from ..mesh.io import Mesh
from .bake import texel_geometry

__all__ = ["Camera", "depth_buffer", "project_views", "ProjectionResult"]


def depth_buffer(V, F, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """Camera-space depth ``z`` of the nearest surface at every pixel centre of an ``(H, W)``
    image (inf where empty): :func:`geoface.gimage.raster.rasterize_mesh` for ``camera`` with its
    image size set to ``shape``.  Triangles with a vertex behind the near plane are skipped;
    depth is perspective-correct (1/z is linear in the image)."""
    H, W = int(shape[0]), int(shape[1])
    if (camera.height, camera.width) != (H, W):
        camera = replace(camera, width=W, height=H)
    near = 1e-9 * bbox_diagonal(np.asarray(V))
    return rasterize_mesh(V, F, camera, near=near)[2]


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample ``img (H, W, C)`` at continuous coordinates ``uv (k, 2)`` whose integers are pixel centres (the camera's ``uv − 0.5``; clamped)."""
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
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= W) & (uv[:, 1] >= 0) & (uv[:, 1] <= H)
        # the depth of the pixel the point falls in: visible when the surface there is not nearer
        col = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, W - 1)
        row = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, H - 1)
        zref = zbuf[row, col]
        visible = inside & np.isfinite(zref) & (z <= zref + tol)
        view = cam.center - X
        cos = (n * view).sum(1) / np.maximum(np.linalg.norm(view, axis=1), 1e-300)
        w = np.where(visible, np.maximum(cos, 0.0) ** power, 0.0) * (cos > 0)
        sel = w > 0
        acc[sel] += w[sel, None] * _bilinear(img, uv[sel] - 0.5)
        wsum += w
        per_view[k, idx] = w
    tex = np.array(dflt, np.float64, copy=True).reshape(-1, 3)
    seen = wsum > 0
    tex[idx[seen]] = acc[seen] / wsum[seen, None]
    weight = np.zeros(T * T)
    weight[idx] = wsum
    return ProjectionResult(tex.reshape(T, T, 3), weight.reshape(T, T), per_view.reshape(-1, T, T))
