"""What is done to an item's stacked image in a geometry-image dataset (:mod:`geoface.ddpm.data`):
block-averaged downsampling to the training resolution (normals back to unit length) and the
seeded rigid augmentation.

Augmentation (seeded; the paper's rigid augmentation) acts in the normalised space, which is
isotropic, so it is rigid in mesh units too: a rotation about the vertical (y) axis by up to
``max_angle`` degrees, a uniform scale in ``scale_range`` and a translation up to
``max_shift``; normals get the same rotation and stay unit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from geoface.errors import GeofaceError


@dataclass(frozen=True)
class AugmentOptions:
    max_angle: float = 30.0          # degrees, rotation about +y
    max_shift: float = 0.05          # translation, normalised units
    scale_range: tuple = (0.9, 1.0)  # uniform scale


def area_resize(image: np.ndarray, mask: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Downsample ``image (C, N, N)`` by averaging the *valid* pixels of each block (N % res == 0)."""
    C, N, _ = image.shape
    if res == N:
        return image, mask
    if res > N or N % res:
        raise GeofaceError(f"training resolution {res} must divide the image resolution {N}")
    k = N // res
    m = mask.astype(np.float32).reshape(res, k, res, k)
    s = (image * mask).reshape(C, res, k, res, k).sum(axis=(2, 4))
    cnt = m.sum(axis=(1, 3))
    out = np.where(cnt > 0, s / np.maximum(cnt, 1), 0.0).astype(np.float32)
    return out, cnt > 0


def unit_normals(n: np.ndarray, full: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Block-averaged normals ``n (3, r, r)`` back to unit length.  Where a block's normals cancel
    (a thin fold seen from both sides) the normal of the block's first pixel in ``full (3, N, N)``
    stands in.  Uncovered pixels stay 0."""
    r = n.shape[-1]
    k = full.shape[-1] // r
    norm = np.linalg.norm(n, axis=0)
    corner = full[:, ::k, ::k]
    out = np.where(norm > 1e-3, n / np.maximum(norm, 1e-12), corner / np.maximum(np.linalg.norm(corner, axis=0), 1e-12))
    return (out * mask[None]).astype(np.float32)


def rigid_augment(x: torch.Tensor, mask: torch.Tensor, gen: torch.Generator,
                  opts: AugmentOptions = AugmentOptions()) -> torch.Tensor:
    """Rotate/scale/shift positions (channels 0-2) and rotate normals (3-5) of ``x [C, R, R]``."""
    u = torch.rand(5, generator=gen, dtype=torch.float64)
    a = math.radians(opts.max_angle) * (2 * float(u[0]) - 1)
    lo, hi = opts.scale_range
    s = lo + (hi - lo) * float(u[1])
    t = torch.tensor([opts.max_shift * (2 * float(u[i]) - 1) for i in (2, 3, 4)], dtype=torch.float32)
    c, sn = math.cos(a), math.sin(a)
    R = torch.tensor([[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]], dtype=torch.float32)
    y = x.clone()
    p = torch.einsum("ij,jhw->ihw", R, x[0:3]) * s + t[:, None, None]
    n = torch.einsum("ij,jhw->ihw", R, x[3:6])
    m = mask.to(x.dtype)
    y[0:3] = p * m
    y[3:6] = n * m
    return y
