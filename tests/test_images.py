"""The one image reader and writer (geoface.images): RGB order kept through OpenCV, 8/16-bit
precision, atomic writes, one-line errors."""
from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.images import ImageFileError, read_image, save_image


def test_rgb_order_and_bits_round_trip(tmp_path):
    img = np.zeros((4, 6, 3))
    img[0, 0] = (1.0, 0.0, 0.0)  # a red marker top-left
    img[3, 5] = (0.0, 0.0, 1.0)  # blue bottom-right
    img[1:3, 1:5] = np.linspace(0, 1, 4)[None, :, None]
    for bits, tol in ((8, 0.5 / 255), (16, 0.5 / 65535)):
        p = tmp_path / f"a{bits}.png"
        save_image(p, img, bits=bits)
        back = read_image(p)
        assert back.dtype == np.float32 and back.shape == (4, 6, 3)
        assert np.abs(back - img).max() <= tol + 1e-7
        raw = read_image(p, as_float=False)
        assert raw.dtype == (np.uint8 if bits == 8 else np.uint16) and raw[0, 0].tolist()[0] == raw.max()
    import cv2

    bgr = cv2.imread(str(tmp_path / "a8.png"))
    assert bgr[0, 0].tolist() == [0, 0, 255]  # on disk a standard PNG: red is red to other readers


def test_gray_rgba_and_errors(tmp_path):
    rgba = np.zeros((3, 3, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 200, 128
    save_image(tmp_path / "a.png", rgba)
    assert read_image(tmp_path / "a.png", "any", as_float=False)[0, 0].tolist() == [200, 0, 0, 128]
    assert read_image(tmp_path / "a.png", "rgb").shape == (3, 3, 3)
    save_image(tmp_path / "m.png", np.eye(3, dtype=bool))
    m = read_image(tmp_path / "m.png", "gray")
    assert m.shape == (3, 3) and m[0, 0] == 1.0 and m[0, 1] == 0.0
    with pytest.raises(ImageFileError, match="no such file"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_bytes(b"not an image at all")
    with pytest.raises(GeofaceError):
        read_image(tmp_path / "bad.png")
    with pytest.raises(ImageFileError, match="must be 4x4"):
        read_image(tmp_path / "a.png", expect_size=(4, 4))
    with pytest.raises(GeofaceError, match="bits"):
        save_image(tmp_path / "x.png", np.zeros((2, 2), np.uint8), bits=16)
    with pytest.raises(GeofaceError, match="an image must be"):
        save_image(tmp_path / "x.png", np.zeros((2, 2, 2)))
    assert not list(tmp_path.glob(".x*"))  # nothing half-written left behind
