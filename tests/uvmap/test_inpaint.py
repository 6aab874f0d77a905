"""Inpainting: valid texels bit-identical, holes filled smoothly, for every method."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.uvmap import dilate_valid, inpaint, push_pull

METHODS = ["pushpull", "biharmonic", "telea"]
# max error of a filled 16×16 hole in a ramp rising by 1 over the image
TOL = {"pushpull": 0.08, "biharmonic": 0.02, "telea": 0.15}


def _ramp(H=48, W=48, dtype=np.float32):
    y, x = np.mgrid[0:H, 0:W]
    return np.stack([x / W, y / H, 0.25 + 0.3 * x / W + 0.2 * y / H], 2).astype(dtype)


def _holes(H=48, W=48):
    m = np.ones((H, W), bool)
    m[14:30, 10:26] = False  # interior hole
    m[40:, 36:] = False  # corner hole
    m[5, 40] = False  # single texel
    return m


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("dilate", [0, 2])
def test_valid_texels_bit_identical_and_holes_filled(method, dilate):
    img = _ramp()
    m = _holes()
    garbage = np.where(m[:, :, None], img, np.nan).astype(np.float32)
    out = inpaint(garbage, m, method=method, dilate=dilate)
    assert out.dtype == img.dtype and out.shape == img.shape
    assert np.array_equal(out[m], img[m])
    assert np.isfinite(out).all()
    # interior hole and single texel: close to the ramp; corner hole (extrapolation): in range
    inner = np.zeros_like(m)
    inner[:32, :] = True
    assert np.abs(out - img)[inner].max() < TOL[method] + (0.04 if dilate else 0.0)  # dilation: ~1 texel of slope per ring
    assert out.min() >= -0.02 and out.max() <= 1.02


def test_pushpull_fills_a_constant_exactly_and_ignores_invalid_values():
    img = np.full((37, 53, 2), 0.3)
    m = np.random.default_rng(0).random((37, 53)) > 0.7
    img[~m] = 1e6  # whatever sits in invalid texels must not leak
    out = push_pull(img, m)
    assert np.allclose(out, 0.3, atol=1e-12)


def test_pushpull_is_smooth_across_a_big_hole():
    img = _ramp(64, 64, np.float64)[:, :, 0]  # 2-D input
    m = np.ones((64, 64), bool)
    m[8:56, 8:56] = False
    out = inpaint(img, m)
    assert out.ndim == 2
    # filled values stay inside the valid range and vary gently from texel to texel
    assert out.min() >= img[m].min() - 1e-12 and out.max() <= img[m].max() + 1e-12
    assert np.abs(np.diff(out, axis=1)).max() < 0.05 and np.abs(np.diff(out, axis=0)).max() < 0.05


def test_integer_images_keep_their_dtype():
    img16 = np.round(_ramp() * 65535).astype(np.uint16)
    m = _holes()
    for method in METHODS:
        out = inpaint(img16, m, method=method)
        assert out.dtype == np.uint16 and np.array_equal(out[m], img16[m])
        assert np.abs(out.astype(float) - img16)[:32].max() < TOL[method] * 65535


def test_dilate_grows_by_k_rings():
    img = np.zeros((21, 21, 1))
    m = np.zeros((21, 21), bool)
    m[10, 10] = True
    img[10, 10] = 2.0
    out, m2 = dilate_valid(img, m, 3)
    assert m2.sum() == 7 * 7 and m2[7:14, 7:14].all()
    assert np.allclose(out[m2], 2.0)


def test_bad_inputs_raise():
    img, m = _ramp(), _holes()
    with pytest.raises(GeofaceError, match="mask must have shape"):
        inpaint(img, m[:, :-1])
    with pytest.raises(GeofaceError, match="method must be one of"):
        inpaint(img, m, method="magic")
    with pytest.raises(GeofaceError, match="no valid texel"):
        inpaint(img, np.zeros_like(m))
    bad = img.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(GeofaceError, match="NaN"):
        inpaint(bad, m)
    with pytest.raises(GeofaceError, match="dilate"):
        inpaint(img, m, dilate=-1)
    with pytest.raises(GeofaceError, match="image must have shape"):
        inpaint(np.zeros((2, 2, 2, 2)), np.ones((2, 2), bool))
