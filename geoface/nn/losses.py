"""Image losses shared by the neural add-ons (pure torch; images are [B, C, H, W]).

* :func:`laplacian_loss` — the 4K-texture paper's high-frequency term: L1 between the 3×3
  Laplacian responses of prediction and target (kernel [[0,1,0],[1,−4,1],[0,1,0]], replicate
  padding, so constant and linear errors cost nothing).
* :func:`ssim` / :func:`dssim` — SSIM with an 11×11 Gaussian window (σ = 1.5, K1 = 0.01,
  K2 = 0.03, data range 1), valid convolution as in skimage's ``gaussian_weights=True``;
  D-SSIM = (1 − SSIM) / 2 (3DGS, THGS, HFM-GS).
"""
from __future__ import annotations

import torch
import torch.nn.functional as Fnn
from torch import Tensor

LAPLACIAN_3x3 = ((0.0, 1.0, 0.0), (1.0, -4.0, 1.0), (0.0, 1.0, 0.0))


def laplacian(img: Tensor) -> Tensor:  # [B, C, H, W] -> [B, C, H, W]
    C = img.shape[1]
    k = torch.tensor(LAPLACIAN_3x3, dtype=img.dtype, device=img.device)[None, None].expand(C, 1, 3, 3)
    return Fnn.conv2d(Fnn.pad(img, (1, 1, 1, 1), mode="replicate"), k, groups=C)


def laplacian_loss(pred: Tensor, target: Tensor) -> Tensor:
    """mean |Δpred − Δtarget| (the paper's L_lap)."""
    return (laplacian(pred) - laplacian(target)).abs().mean()


def _gauss_window(size: int, sigma: float, C: int, like: Tensor) -> Tensor:
    x = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    g = g / g.sum()
    return (g[:, None] * g[None])[None, None].expand(C, 1, size, size)


def ssim(a: Tensor, b: Tensor, window: int = 11, sigma: float = 1.5, data_range: float = 1.0,
         k1: float = 0.01, k2: float = 0.03) -> Tensor:
    """Mean SSIM of [B, C, H, W] images (valid region; every side must be ≥ ``window``)."""
    C = a.shape[1]
    w = _gauss_window(window, sigma, C, a)
    mu_a, mu_b = Fnn.conv2d(a, w, groups=C), Fnn.conv2d(b, w, groups=C)
    saa = Fnn.conv2d(a * a, w, groups=C) - mu_a**2
    sbb = Fnn.conv2d(b * b, w, groups=C) - mu_b**2
    sab = Fnn.conv2d(a * b, w, groups=C) - mu_a * mu_b
    c1, c2 = (k1 * data_range) ** 2, (k2 * data_range) ** 2
    s = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (saa + sbb + c2))
    return s.mean()


def dssim(a: Tensor, b: Tensor, **kw) -> Tensor:
    return (1 - ssim(a, b, **kw)) / 2
