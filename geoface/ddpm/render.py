"""Shaded renders of heads for evaluation: fixed cameras, fixed lights, no texture.

The DDPM's samples and real heads are judged on what they look like, as the head-synthesis
paper does: each is reconstructed to a mesh, aligned to a reference head (optional), and
rendered off-screen (pyvista) from the same cameras with the same lights, in grey.

>>> r = HeadRenderer(center=(0, 0, 0), scale=20.0, size=64)        # doctest: +SKIP
>>> img = r.render(V, F)   # (views, 64, 64) float32 in [0, 1]         # doctest: +SKIP
"""
from __future__ import annotations

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["HeadRenderer", "VIEWS", "similarity_align", "grid_image"]

#: camera directions (from the centre towards the camera), +y up, +z the face's front
VIEWS = {"front": (0.0, 0.0, 1.0), "three_quarter": (0.6, 0.15, 0.8), "three_quarter_right": (-0.6, 0.15, 0.8),
         "side": (1.0, 0.0, 0.0)}


class HeadRenderer:
    """Off-screen grey renders of meshes from fixed cameras around ``center``.

    Parameters
    ----------
    center, scale : the frame: cameras look at ``center`` from ``distance * scale`` away, the
        view fitting a sphere of radius ``scale`` (e.g. a dataset :class:`~geoface.ddpm.data.Normalization`)
    size : image side in pixels
    views : names in :data:`VIEWS`
    """

    def __init__(self, center=(0.0, 0.0, 0.0), scale: float = 1.0, *, size: int = 96, views=("front", "three_quarter"),
                 distance: float = 4.0):
        from geoface._lazy import lazy_import

        self.pv = lazy_import("pyvista", "rendering heads")
        bad = [v for v in views if v not in VIEWS]
        if bad:
            raise GeofaceError(f"unknown views {bad}; views are {', '.join(VIEWS)}")
        if not (np.isfinite(scale) and scale > 0):
            raise GeofaceError(f"scale must be positive; got {scale!r}")
        self.center, self.scale, self.size = np.asarray(center, np.float64), float(scale), int(size)
        self.views, self.distance = tuple(views), float(distance)
        self._pl = None

    def _plotter(self):
        if self._pl is None:
            pv = self.pv
            pl = pv.Plotter(off_screen=True, window_size=(self.size, self.size))
            pl.set_background("black")
            pl.remove_all_lights()
            # fixed in the scene, not in the camera: every view sees the same lighting
            c, s = self.center, self.scale
            pl.add_light(pv.Light(position=tuple(c + s * np.array([1.5, 2.0, 4.0])), focal_point=tuple(c),
                                  light_type="scene light", intensity=0.8))
            pl.add_light(pv.Light(position=tuple(c + s * np.array([-3.0, 0.5, 2.0])), focal_point=tuple(c),
                                  light_type="scene light", intensity=0.35))
            self._pl = pl
        return self._pl

    def render(self, V, F) -> np.ndarray:
        """``(len(views), size, size)`` float32 grey values in [0, 1] (background 0)."""
        pv = self.pv
        V = np.asarray(V, np.float64)
        F = np.asarray(F, np.int64)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0 or not np.isfinite(V).all():
            raise GeofaceError("render needs finite (n, 3) vertices and a non-empty (m, 3) face array")
        pl = self._plotter()
        mesh = pv.PolyData(V, np.hstack([np.full((len(F), 1), 3), F]).ravel())
        actor = pl.add_mesh(mesh, color="white", smooth_shading=True, ambient=0.1, diffuse=0.9, specular=0.0)
        out = []
        try:
            for name in self.views:
                d = np.asarray(VIEWS[name], np.float64)
                d /= np.linalg.norm(d)
                cam = pl.camera
                cam.focal_point = tuple(self.center)
                cam.position = tuple(self.center + self.distance * self.scale * d)
                cam.up = (0.0, 1.0, 0.0)
                cam.view_angle = float(np.degrees(2 * np.arcsin(1.0 / self.distance)))
                cam.clipping_range = (0.1 * self.scale, (self.distance + 2) * self.scale)
                pl.render()
                img = pl.screenshot(return_img=True)
                out.append(np.asarray(img[..., :3], np.float32).mean(-1) / 255.0)
        finally:
            pl.remove_actor(actor)
        return np.stack(out)

    def close(self) -> None:
        if self._pl is not None:
            self._pl.close()
            self._pl = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def similarity_align(P: np.ndarray, Q: np.ndarray, mask=None) -> np.ndarray:
    """``P`` moved by the similarity transform (rotation, uniform scale, translation) that best
    maps it onto ``Q`` over corresponding points (Umeyama 1991); ``P, Q (n, 3)``, ``mask (n,)``
    the points to fit on (default all).

    >>> P = np.random.default_rng(0).normal(size=(10, 3))
    >>> bool(np.allclose(similarity_align(2 * P + 1, P), P))
    True
    """
    from geoface.mesh.align import similarity_transform

    P = np.asarray(P, np.float64)
    s, R, t = similarity_transform(P, Q, mask)
    return P @ (s * R).T + t


def grid_image(tiles: np.ndarray, *, gap: int = 2, row_labels=None, col_labels=None) -> np.ndarray:
    """``tiles (rows, cols, H, W)`` grey in [0, 1] → one ``uint8`` image with ``gap``-pixel white
    lines; ``row_labels`` (one per row) are written in a band on the left, ``col_labels`` (one per
    column, ``""`` for none) above the columns."""
    import cv2

    t = np.asarray(tiles, np.float32)
    r, c, h, w = t.shape
    if row_labels is not None and len(row_labels) != r:
        raise ValueError(f"row_labels: {len(row_labels)} for {r} rows")
    if col_labels is not None and len(col_labels) != c:
        raise ValueError(f"col_labels: {len(col_labels)} for {c} columns")
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, max(0.3, h / 160), 1
    text_w = lambda s: cv2.getTextSize(s, font, scale, thick)[0][0]  # noqa: E731
    left = (max(text_w(s) for s in row_labels) + 3 * gap) if row_labels is not None else 0
    top = (cv2.getTextSize("Ag", font, scale, thick)[0][1] + 4 * gap) if col_labels is not None else 0
    out = np.ones((top + r * (h + gap) + gap, left + c * (w + gap) + gap), np.float32)
    for i in range(r):
        for j in range(c):
            y, x = top + gap + i * (h + gap), left + gap + j * (w + gap)
            out[y: y + h, x: x + w] = t[i, j]
    img = np.round(np.clip(out, 0, 1) * 255).astype(np.uint8)
    for i, s in enumerate(row_labels or []):
        y = top + gap + i * (h + gap) + h // 2 + 4
        cv2.putText(img, str(s), (gap, y), font, scale, 0, thick, cv2.LINE_AA)
    for j, s in enumerate(col_labels or []):
        cv2.putText(img, str(s), (left + gap + j * (w + gap) + 2, top - 2 * gap), font, scale, 0, thick, cv2.LINE_AA)
    return img
