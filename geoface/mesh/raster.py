"""A z-buffered rasterizer of a triangle mesh through a pinhole camera, in NumPy: which triangle
each pixel centre sees, where on it (perspective-correct barycentric weights) and how deep.  It is
the library's one camera-space z-buffer: photo projection onto UVs, the torch renderers' visibility,
and the renders of a scan that the face tracker looks at (:mod:`geoface.track.scan`) all use it.
Triangles are processed in chunks, each enumerating the pixel centres of its bounding box, so
memory stays bounded."""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..errors import InvalidMeshError, RenderError
from .core import check_mesh

__all__ = ["bbox_pixels", "rasterize_mesh"]


def bbox_pixels(x, y, det, j0, i0, nj, count, chunk: int):
    """Enumerate the pixel centres in triangles' bounding boxes, in chunks of about ``chunk``.

    ``x, y (m, 3)``: vertex pixel coordinates (centres at integers); ``det (m,)``: twice the
    signed area; ``j0, i0 (m,)``: first column/row of each box; ``nj (m,)``: box width;
    ``count (m,)``: pixels in the box (0 skips the triangle).  Yields
    ``(tt, ii, jj, b0, b1, b2)``: triangle, row, column and barycentric coordinates of every
    enumerated pixel (inside or not: the caller tests the signs).
    """
    tri = np.flatnonzero(count)
    csum = np.cumsum(count[tri])
    start = 0
    while start < len(tri):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + chunk, side="right")), start + 1)
        t = tri[start:stop]
        c = count[t]
        rep = np.repeat(np.arange(len(t)), c)
        local = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        tt = t[rep]
        jj = j0[tt] + local % nj[tt]
        ii = i0[tt] + local // nj[tt]
        px = jj.astype(np.float64)
        py = ii.astype(np.float64)
        xa, ya = x[tt], y[tt]
        d = det[tt]
        b1 = ((px - xa[:, 0]) * (ya[:, 2] - ya[:, 0]) - (xa[:, 2] - xa[:, 0]) * (py - ya[:, 0])) / d
        b2 = ((xa[:, 1] - xa[:, 0]) * (py - ya[:, 0]) - (px - xa[:, 0]) * (ya[:, 1] - ya[:, 0])) / d
        yield tt, ii, jj, 1.0 - b1 - b2, b1, b2
        start = stop


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
    try:
        V, F = check_mesh(V, F, allow_empty=True)
    except InvalidMeshError as e:
        raise RenderError(str(e)) from None
    if not isinstance(camera, Camera):
        raise RenderError(f"camera must be a geoface.camera.Camera; got {type(camera).__name__}")
    H, W = camera.height, camera.width
    uv, z = camera.project(V)
    x, y, zf = uv[F, 0] - 0.5, uv[F, 1] - 0.5, z[F]  # bbox_pixels: pixel centres at integers
    det = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    # the corners' extremes column by column (a reduction along a length-3 axis is several times slower)
    xlo, xhi = np.minimum(np.minimum(x[:, 0], x[:, 1]), x[:, 2]), np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2])
    ylo, yhi = np.minimum(np.minimum(y[:, 0], y[:, 1]), y[:, 2]), np.maximum(np.maximum(y[:, 0], y[:, 1]), y[:, 2])
    j0 = np.clip(np.ceil(xlo), 0, W - 1).astype(np.int64)
    j1 = np.clip(np.floor(xhi), 0, W - 1).astype(np.int64)
    i0 = np.clip(np.ceil(ylo), 0, H - 1).astype(np.int64)
    i1 = np.clip(np.floor(yhi), 0, H - 1).astype(np.int64)
    on = ((det != 0) & (np.minimum(np.minimum(zf[:, 0], zf[:, 1]), zf[:, 2]) > near) & (xhi >= 0) & (xlo <= W - 1)
          & (yhi >= 0) & (ylo <= H - 1))
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
