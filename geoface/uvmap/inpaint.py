"""Fill the empty texels of a baked texture.

Three methods, one contract: valid texels come back bit-identical, every other texel gets a
finite value.

- ``"pushpull"`` (default): the push–pull pyramid (Gortler et al. 1996).  *Push*: halve the
  image repeatedly, each coarse texel the weight-averaged 2×2 block, weights ``min(1, Σw)``.
  *Pull*: from the coarsest level down, bilinearly upsample and blend
  ``c = w·c_fine + (1 − w)·up(c_coarse)``.  Vectorised numpy, O(HW).
- ``"biharmonic"``: ``skimage.restoration.inpaint_biharmonic`` (smoothest, slow on big holes).
- ``"telea"``: ``cv2.inpaint(..., INPAINT_TELEA)``; OpenCV wants 8-bit, so each channel is
  mapped to 8 bits over its own valid range, inpainted, and mapped back (filled texels carry
  1/255 of the range as quantisation; valid texels are restored exactly).

``dilate=k`` first grows the valid region by ``k`` texels (each new texel the mean of its valid
8-neighbours), the usual seam padding against bleeding under mip-mapping.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from .._lazy import lazy_import
from ..errors import GeofaceError

__all__ = ["inpaint", "push_pull", "dilate_valid"]

Method = Literal["pushpull", "biharmonic", "telea"]
METHODS = ("pushpull", "biharmonic", "telea")


def _check(image, mask) -> tuple[np.ndarray, np.ndarray, bool]:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] < 1 or img.shape[1] < 1:
        raise GeofaceError(f"image must have shape (H, W) or (H, W, C); got {img.shape}")
    if not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)):
        raise GeofaceError(f"image must be numeric; got dtype {img.dtype}")
    m = np.asarray(mask)
    if m.shape != img.shape[:2]:
        raise GeofaceError(f"mask must have shape {img.shape[:2]} (the image's H, W); got {m.shape}")
    m = m.astype(bool)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[:, :, None]
    if np.issubdtype(img.dtype, np.floating) and not np.isfinite(img[m]).all():
        raise GeofaceError("image has NaN or infinite values at valid (mask True) texels")
    return img, m, squeeze


def _down(c: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One push step: premultiplied 2×2 sums (odd sizes padded with zero weight)."""
    H, W = w.shape
    ph, pw = H % 2, W % 2
    if ph or pw:
        c = np.pad(c, ((0, ph), (0, pw), (0, 0)))
        w = np.pad(w, ((0, ph), (0, pw)))
    cw = c * w[:, :, None]
    s = cw[0::2, 0::2] + cw[1::2, 0::2] + cw[0::2, 1::2] + cw[1::2, 1::2]
    ws = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
    cc = np.divide(s, ws[:, :, None], out=np.zeros_like(s), where=ws[:, :, None] > 0)
    return cc, np.minimum(ws, 1.0)


def _up(c: np.ndarray, H: int, W: int) -> np.ndarray:
    """Bilinear ×2 upsampling with half-pixel centres (fine 2i ↔ coarse i − ¼), cropped to H×W."""
    def axis(a, ax):
        n = a.shape[ax]
        prev = np.take(a, np.clip(np.arange(n) - 1, 0, n - 1), axis=ax)
        nxt = np.take(a, np.clip(np.arange(n) + 1, 0, n - 1), axis=ax)
        even, odd = 0.75 * a + 0.25 * prev, 0.75 * a + 0.25 * nxt
        out = np.stack([even, odd], axis=ax + 1)
        shp = list(a.shape)
        shp[ax] = 2 * n
        return out.reshape(shp)
    return axis(axis(c, 0), 1)[:H, :W]


def push_pull(image, mask) -> np.ndarray:
    """Push–pull fill of ``image (H, W[, C])`` where ``mask`` is False; float64 result with the
    valid texels' values converted to float64 unchanged (callers restore the dtype)."""
    img, m, squeeze = _check(image, mask)
    c = np.where(m[:, :, None], img.astype(np.float64), 0.0)
    w = m.astype(np.float64)
    levels = [(c, w)]
    while max(w.shape) > 1 and not (levels[-1][1] > 0).all():
        c, w = _down(c, w)
        levels.append((c, w))
        if not (w > 0).any():  # nothing valid at all
            break
    c = levels[-1][0]
    for cf, wf in reversed(levels[:-1]):
        up = _up(c, *wf.shape)
        c = wf[:, :, None] * cf + (1.0 - wf[:, :, None]) * up
    out = np.where(m[:, :, None], img.astype(np.float64), c)
    return out[:, :, 0] if squeeze else out


def dilate_valid(image, mask, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Grow the valid region by ``k`` texels: each ring's texels get the mean of their valid
    8-neighbours.  Returns ``(image float64, mask)``; originally valid texels are unchanged."""
    img, m, squeeze = _check(image, mask)
    if isinstance(k, bool) or int(k) != k or k < 0:
        raise GeofaceError(f"dilate must be an integer >= 0; got {k!r}")
    c = np.where(m[:, :, None], img.astype(np.float64), 0.0)
    m = m.copy()
    H, W = m.shape
    for _ in range(int(k)):
        if m.all() or not m.any():
            break
        cp = np.pad(c * m[:, :, None], ((1, 1), (1, 1), (0, 0)))
        mp = np.pad(m.astype(np.float64), 1)
        s = np.zeros_like(c)
        n = np.zeros(m.shape)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di or dj:
                    s += cp[1 + di:1 + di + H, 1 + dj:1 + dj + W]
                    n += mp[1 + di:1 + di + H, 1 + dj:1 + dj + W]
        grow = ~m & (n > 0)
        c[grow] = s[grow] / n[grow][:, None]
        m |= grow
    out = np.where(m[:, :, None], c, 0.0)
    return (out[:, :, 0] if squeeze else out), m


def _telea(c: np.ndarray, m: np.ndarray, radius: float) -> np.ndarray:
    cv2 = lazy_import("cv2", "Telea inpainting")
    hole = (~m).astype(np.uint8)
    out = c.copy()
    for k in range(c.shape[2]):
        ch = c[:, :, k]
        lo, hi = float(ch[m].min()), float(ch[m].max())
        span = hi - lo if hi > lo else 1.0
        q = np.round(np.clip((ch - lo) / span, 0.0, 1.0) * 255.0).astype(np.uint8)
        f = cv2.inpaint(q, hole, float(radius), cv2.INPAINT_TELEA)
        out[:, :, k] = lo + f.astype(np.float64) / 255.0 * span
    return out


def inpaint(image, mask, *, method: Method = "pushpull", dilate: int = 0, radius: float = 3.0) -> np.ndarray:
    """Fill the texels of ``image`` where ``mask`` is False.

    Parameters
    ----------
    image : (H, W) or (H, W, C) float or integer array (uint8/uint16 results are rounded back)
    mask : (H, W) bool, True at valid texels; these are returned bit-identical
    method : ``"pushpull"`` (default), ``"biharmonic"`` or ``"telea"``
    dilate : grow the valid region by this many texels first (seam padding)
    radius : Telea's neighbourhood radius in texels

    Returns
    -------
    (H, W[, C]) array of the input dtype, finite everywhere (at least one texel must be valid).

    Examples
    --------
    >>> import numpy as np
    >>> img = np.tile(np.linspace(0, 1, 8), (8, 1)); m = np.ones((8, 8), bool); m[3:5, 3:5] = False
    >>> out = inpaint(img, m)
    >>> bool(np.array_equal(out[m], img[m])), bool(np.isfinite(out).all())
    (True, True)
    """
    img, m, squeeze = _check(image, mask)
    if method not in METHODS:
        raise GeofaceError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    if not m.any():
        raise GeofaceError("mask has no valid texel: nothing to inpaint from")
    c, mv = dilate_valid(img, m, dilate) if dilate else (np.where(m[:, :, None], img.astype(np.float64), 0.0), m)
    if not mv.all():
        if method == "pushpull":
            c = push_pull(c, mv)
        elif method == "biharmonic":
            restoration = lazy_import("skimage.restoration", "biharmonic inpainting")
            c = restoration.inpaint_biharmonic(np.where(mv[:, :, None], c, 0.0), ~mv, channel_axis=-1)
        else:
            c = _telea(c, mv, radius)
    if np.issubdtype(img.dtype, np.integer):
        info = np.iinfo(img.dtype)
        c = np.clip(np.round(c), info.min, info.max)
    out = c.astype(img.dtype)
    out[m] = img[m]  # valid texels: bit-identical, whatever the method did
    return out[:, :, 0] if squeeze else out
