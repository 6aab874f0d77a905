"""A z-buffered rasterizer of a triangle mesh through a pinhole camera, in NumPy: which triangle
each pixel centre sees, where on it (perspective-correct barycentric weights) and how deep.  It is
the library's one camera-space z-buffer: photo projection onto UVs, the torch renderers' visibility,
and the renders of a scan that the face tracker looks at (:mod:`geoface.track.scan`) all use it.
Triangles are processed in chunks, each enumerating the pixel centres of its bounding box, so
memory stays bounded; where the compiled z-buffer (``geoface.mesh._native.zbuffer``, built by
``setup.py``) is there, it runs the same loop, with the same arithmetic, in C++."""

from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._lazy import native_library
from ..camera import Camera
from ..errors import InvalidMeshError, RenderError
from .core import check_mesh

__all__ = ["bbox_pixels", "rasterize_mesh"]


@lru_cache(maxsize=1)
def _native_zbuffer():
    """The compiled z-buffer loop (``geoface_zbuffer``), or None where it was not built."""
    lib = native_library(Path(__file__).with_name("_native"), "zbuffer", "geoface_zbuffer_abi")
    if lib is None:
        return None
    fn = lib.geoface_zbuffer
    fn.restype = None
    fn.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 9 + [ctypes.c_int64] + [ctypes.c_void_p] * 3
    return fn


def bbox_pixels(x, y, det, j0, i0, nj, count, chunk: int):
    """Enumerate the pixel centres of triangles, in chunks of about ``chunk`` (bounding-box pixels).

    ``x, y (m, 3)``: vertex pixel coordinates (centres at integers); ``det (m,)``: twice the
    signed area; ``j0, i0 (m,)``: first column/row of each bounding box; ``nj (m,)``: box width;
    ``count (m,)``: pixels in the box (0 skips the triangle). Each row of a box is cut to the
    span between the triangle's edges there (widened by :data:`SPAN_SLACK` of a pixel), so a
    sliver's box costs no more than its pixels. Yields ``(tt, ii, jj, b0, b1, b2)``: triangle,
    row, column and barycentric coordinates of every enumerated pixel (inside or not, near an
    edge: the caller tests the signs).
    """
    tri = np.flatnonzero(count)
    csum = np.cumsum(count[tri])
    start = 0
    while start < len(tri):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + chunk, side="right")), start + 1)
        t = tri[start:stop]
        start = stop
        # one (triangle, row) pair per row of each box, cut to the edges' span on that row
        ni = count[t] // nj[t]
        pt = np.repeat(t, ni)
        row = i0[pt] + (np.arange(len(pt)) - np.repeat(np.cumsum(ni) - ni, ni))
        yr = row.astype(np.float64)
        X, Y = x[pt], y[pt]
        lo = np.full(len(pt), np.inf)
        hi = np.full(len(pt), -np.inf)
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ya, yb, xa, xb = Y[:, a], Y[:, b], X[:, a], X[:, b]
            on = (np.minimum(ya, yb) <= yr) & (yr <= np.maximum(ya, yb))
            dy = yb - ya
            flat = dy == 0
            with np.errstate(divide="ignore", invalid="ignore"):
                xi = xa + (yr - ya) * (xb - xa) / np.where(flat, 1.0, dy)
            lo = np.where(on, np.minimum(lo, np.where(flat, np.minimum(xa, xb), xi)), lo)
            hi = np.where(on, np.maximum(hi, np.where(flat, np.maximum(xa, xb), xi)), hi)
        ok = np.isfinite(lo) & np.isfinite(hi)
        jl = np.maximum(np.ceil(np.where(ok, lo, 0.0) - SPAN_SLACK), j0[pt]).astype(np.int64)
        jr = np.minimum(np.floor(np.where(ok, hi, -1.0) + SPAN_SLACK), j0[pt] + nj[pt] - 1).astype(np.int64)
        c = np.where(ok, np.maximum(jr - jl + 1, 0), 0)
        keep = c > 0
        pt, row, jl, c = pt[keep], row[keep], jl[keep], c[keep]
        if not len(pt):
            continue
        rep = np.repeat(np.arange(len(pt)), c)
        tt = pt[rep]
        ii = row[rep]
        jj = jl[rep] + (np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c))
        px = jj.astype(np.float64)
        py = ii.astype(np.float64)
        xa, ya = x[tt], y[tt]
        d = det[tt]
        b1 = ((px - xa[:, 0]) * (ya[:, 2] - ya[:, 0]) - (xa[:, 2] - xa[:, 0]) * (py - ya[:, 0])) / d
        b2 = ((xa[:, 1] - xa[:, 0]) * (py - ya[:, 0]) - (px - xa[:, 0]) * (ya[:, 1] - ya[:, 0])) / d
        yield tt, ii, jj, 1.0 - b1 - b2, b1, b2


#: a row's span between a triangle's edges is widened by this share of a pixel on each side
#: (pixel centres on an edge, to rounding, are enumerated; the caller's sign test decides)
SPAN_SLACK = 1e-5


def rasterize_mesh(V, F, camera: Camera, *, near: float = 1e-6, chunk: int = 2_000_000, native: bool = True):
    """Nearest triangle per pixel centre.

    Parameters
    ----------
    V : (n, 3) float64 world positions; F : (m, 3) int64 triangles
    camera : Camera
    near : triangles with a vertex at camera depth ``<= near`` are skipped
    native : the compiled loop where it is built (False: the NumPy loop, which writes the same)

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
    zbuf = np.full(H * W, np.inf)
    face = np.full(H * W, -1, dtype=np.int64)
    bary = np.zeros((H * W, 3))
    native = _native_zbuffer() if native else None
    if native is not None:  # the same loop in C++: triangles in order, the first of equally near ones kept
        c = [np.ascontiguousarray(a, np.float64) for a in (x, y, zf, det)] + \
            [np.ascontiguousarray(a, np.int64) for a in (j0, j1, i0, i1)] + [np.ascontiguousarray(on, np.uint8)]
        native(len(F), *(a.ctypes.data for a in c), W, zbuf.ctypes.data, face.ctypes.data, bary.ctypes.data)
        return face.reshape(H, W), bary.reshape(H, W, 3), zbuf.reshape(H, W)
    nj = np.maximum(j1 - j0 + 1, 1)
    count = np.where(on, nj * np.maximum(i1 - i0 + 1, 0), 0)
    for tt, ii, jj, b0, b1, b2 in bbox_pixels(x, y, det, j0, i0, nj, count, chunk):
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        tt, pix = tt[inside], ii[inside] * W + jj[inside]
        w = np.clip(np.stack([b0[inside], b1[inside], b2[inside]], 1), 0.0, None) / zf[tt]
        zc = 1.0 / w.sum(1)  # perspective-correct depth: 1/z is linear on screen
        # the nearest candidate of each pixel, and nearer than what earlier chunks left: the
        # z-buffer by an unbuffered minimum (no sort); of equally near ones the first is kept
        before = zbuf[pix]
        np.minimum.at(zbuf, pix, zc)
        k = np.flatnonzero((zc == zbuf[pix]) & (zc < before))[::-1]  # reversed: the first written last
        face[pix[k]] = tt[k]
        bary[pix[k]] = w[k] * zc[k, None]
    return face.reshape(H, W), bary.reshape(H, W, 3), zbuf.reshape(H, W)
