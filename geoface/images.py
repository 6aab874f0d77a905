"""Reading and writing images: one reader and one writer for the whole library.

Arrays are in **RGB order** (OpenCV's BGR stays inside), rows top to bottom. :func:`read_image`
returns float32 in [0, 1] (8- and 16-bit files alike) or the file's own integers;
:func:`save_image` takes floats in [0, 1] or uint8/uint16 and writes 8- or 16-bit PNG (or any
format OpenCV encodes, by the extension), atomically: the file appears complete or not at all.

>>> import numpy as np, tempfile, os
>>> p = os.path.join(tempfile.mkdtemp(), "a.png")
>>> save_image(p, np.array([[[1.0, 0.5, 0.0]]]), bits=16)
>>> read_image(p).round(4).tolist()
[[[1.0, 0.5, 0.0]]]
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np

from .errors import GeofaceError

__all__ = ["read_image", "save_image", "ImageFileError"]


class ImageFileError(GeofaceError):
    """An image file that is missing, not an image, or not of the size or kind asked for."""


def read_image(path: str | os.PathLike, channels: Literal["rgb", "gray", "any"] = "rgb", *, as_float: bool = True,
               expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """Read ``path``: ``channels="rgb"`` gives ``(H, W, 3)`` (grey repeated, alpha dropped),
    ``"gray"`` ``(H, W)`` (the first channel), ``"any"`` what the file holds (RGB or RGBA order).
    ``as_float``: float32 in [0, 1]; else the file's uint8/uint16. ``expect_size (W, H)`` is checked
    from the header before the pixels are decoded. Errors are :class:`ImageFileError`."""
    from ._io import image_size

    path = Path(path)
    if not path.is_file():
        raise ImageFileError(f"{path}: no such file")
    try:
        size = image_size(path)
    except (GeofaceError, OSError) as e:
        raise ImageFileError(f"{path}: {e}") from None
    if expect_size is not None and size is not None and tuple(size) != tuple(expect_size):
        raise ImageFileError(f"{path.name} must be {expect_size[0]}x{expect_size[1]}; its header says {size[0]}x{size[1]}")
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if a is None:
        raise ImageFileError(f"{path}: not a readable image")
    if a.ndim == 3:
        a = a[..., [2, 1, 0, 3]] if a.shape[2] == 4 else a[..., ::-1]  # BGR(A) -> RGB(A)
    if channels == "rgb":
        a = np.repeat(a[..., None], 3, -1) if a.ndim == 2 else a[..., :3]
    elif channels == "gray":
        a = a[..., 0] if a.ndim == 3 else a
    elif channels != "any":
        raise GeofaceError(f"channels must be 'rgb', 'gray' or 'any'; got {channels!r}")
    if as_float:
        a = a.astype(np.float32) / (65535.0 if a.dtype == np.uint16 else 255.0)
    return np.ascontiguousarray(a)


def save_image(path: str | os.PathLike, image, *, bits: int | None = None, atomic: bool = True) -> None:
    """Write ``image`` (``(H, W)``, ``(H, W, 1|3|4)``; RGB(A) order) to ``path``. Floats are read
    as [0, 1] (clipped) and written with ``bits`` (8 by default, or 16); uint8/uint16 are written
    as they are (``bits`` must then match or be None). ``atomic``: through a temporary file in the
    same folder, renamed when complete."""
    from ._io import atomic_path, write_image

    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or a.size == 0:
        raise GeofaceError(f"an image must be (H, W), (H, W, 1), (H, W, 3) or (H, W, 4); got {a.shape}")
    if a.dtype in (np.uint8, np.uint16):
        if bits is not None and bits != 8 * a.dtype.itemsize:
            raise GeofaceError(f"a {a.dtype} image is written with {8 * a.dtype.itemsize} bits; got bits={bits}")
    else:
        bits = 8 if bits is None else int(bits)
        if bits not in (8, 16):
            raise GeofaceError(f"bits must be 8 or 16; got {bits}")
        top = 255 if bits == 8 else 65535
        a = np.round(np.clip(np.nan_to_num(a.astype(np.float64)), 0.0, 1.0) * top).astype(np.uint8 if bits == 8 else np.uint16)
    if a.ndim == 3:
        a = a[..., [2, 1, 0, 3]] if a.shape[2] == 4 else a[..., ::-1]  # RGB(A) -> BGR(A) for OpenCV
    a = np.ascontiguousarray(a)
    path = Path(path)
    if not atomic:
        write_image(path, a)
        return
    with atomic_path(path, suffix=path.suffix or ".png") as tmp:
        write_image(tmp, a)
