"""Patch tiling for full-resolution texture inference (4K-texture paper, HFDR stage).

An image of H×W is cut into k×k patches (H and W divisible by k); :func:`split_patches` and
:func:`assemble_patches` are exact inverses.  Guidance maps at any resolution (the GDE output
at 1024², UV, normals) are resampled to the full resolution and cropped to the same boxes by
:func:`guidance_crop`.  After assembly, :func:`smooth_seams` blurs only a band around each
internal seam with an anisotropic Gaussian whose long axis crosses the seam (16 px across ×
2 px along, σ = 5, the paper's 2×16 / 16×2 kernels written width × height).
:func:`stream_patches` runs a per-patch function and writes each result straight into the
output, so peak memory is one patch of work plus the output array, whatever the input size.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as Fnn
from torch import Tensor

from ..errors import LearnError


def _check(shape, k: int) -> tuple[int, int]:
    H, W = shape[-2], shape[-1]
    if k < 1 or H % k or W % k:
        raise LearnError(f"image size {H}x{W} must be divisible by the patch grid k={k}")
    return H // k, W // k


def patch_boxes(H: int, W: int, k: int) -> Iterator[tuple[int, int, slice, slice]]:
    """(row, col, y-slice, x-slice) of each patch, row-major."""
    ph, pw = _check((H, W), k)
    for i in range(k):
        for j in range(k):
            yield i, j, slice(i * ph, (i + 1) * ph), slice(j * pw, (j + 1) * pw)


def split_patches(img: Tensor, k: int) -> Tensor:  # [B, C, H, W] -> [B, k*k, C, H/k, W/k]
    """Cut into k×k patches (row-major), one reshape: no copy of pixel values is altered."""
    B, C, H, W = img.shape
    ph, pw = _check(img.shape, k)
    return img.reshape(B, C, k, ph, k, pw).permute(0, 2, 4, 1, 3, 5).reshape(B, k * k, C, ph, pw)


def assemble_patches(patches: Tensor, k: int) -> Tensor:  # [B, k*k, C, ph, pw] -> [B, C, H, W]
    """Exact inverse of :func:`split_patches`."""
    B, n, C, ph, pw = patches.shape
    if n != k * k:
        raise LearnError(f"expected {k * k} patches for k={k}; got {n}")
    return patches.reshape(B, k, k, C, ph, pw).permute(0, 3, 1, 4, 2, 5).reshape(B, C, k * ph, k * pw)


def guidance_crop(guide: Tensor, size: tuple[int, int], box: tuple[slice, slice],
                  mode: str = "bilinear") -> Tensor:
    """The part of ``guide`` [B, C, h, w] covering ``box`` of a full-resolution image of
    ``size`` (H, W), resampled to the box's pixel size (align_corners=False geometry).

    Only the crop is interpolated (plus a one-texel margin), so memory is per patch.
    """
    H, W = size
    B, C, h, w = guide.shape
    ys, xs = box
    sy, sx = h / H, w / W
    # guide-space span of the box, with a margin for the bilinear footprint
    gy0, gy1 = max(int(math.floor(ys.start * sy)) - 1, 0), min(int(math.ceil(ys.stop * sy)) + 1, h)
    gx0, gx1 = max(int(math.floor(xs.start * sx)) - 1, 0), min(int(math.ceil(xs.stop * sx)) + 1, w)
    sub = guide[:, :, gy0:gy1, gx0:gx1]
    ny, nx = ys.stop - ys.start, xs.stop - xs.start
    # sample points: full-res pixel centres → guide coordinates → normalised coords of ``sub``
    py = ((torch.arange(ys.start, ys.stop, dtype=guide.dtype, device=guide.device) + 0.5) * sy - 0.5)
    px = ((torch.arange(xs.start, xs.stop, dtype=guide.dtype, device=guide.device) + 0.5) * sx - 0.5)
    py = py.clamp(0, h - 1) - gy0
    px = px.clamp(0, w - 1) - gx0
    gy = (py + 0.5) / sub.shape[-2] * 2 - 1
    gx = (px + 0.5) / sub.shape[-1] * 2 - 1
    grid = torch.stack(torch.meshgrid(gy, gx, indexing="ij")[::-1], -1)[None].expand(B, ny, nx, 2)
    return Fnn.grid_sample(sub, grid, mode=mode, padding_mode="border", align_corners=False)


def gaussian_kernel(height: int, width: int, sigma: float = 5.0) -> Tensor:
    """Separable Gaussian kernel of ``height`` × ``width`` taps (normalised to sum 1)."""
    def g(n):
        x = torch.arange(n, dtype=torch.float64) - (n - 1) / 2
        v = torch.exp(-0.5 * (x / sigma) ** 2)
        return v / v.sum()
    return (g(height)[:, None] * g(width)[None]).float()


def _centred(ker: Tensor) -> Tensor:
    """An even-sized kernel has no centre pixel: average its two half-pixel placements along
    each even axis (a convolution with [½, ½]), giving an odd, symmetric kernel with the same
    sum, so smoothing does not shift the image by half a pixel."""
    for axis in (0, 1):
        if ker.shape[axis] % 2 == 0:
            z = torch.zeros_like(ker.narrow(axis, 0, 1))
            ker = 0.5 * (torch.cat([ker, z], axis) + torch.cat([z, ker], axis))
    return ker


def seam_masks(H: int, W: int, k: int, band: int = 8) -> tuple[Tensor, Tensor]:
    """Boolean [H, W] masks of the bands (``band`` px wide, centred) around the internal
    horizontal seams (y = i·H/k) and the vertical seams (x = j·W/k)."""
    ph, pw = _check((H, W), k)
    hm = torch.zeros(H, W, dtype=torch.bool)
    vm = torch.zeros(H, W, dtype=torch.bool)
    half = band // 2
    for i in range(1, k):
        hm[max(i * ph - half, 0):i * ph + band - half] = True
    for j in range(1, k):
        vm[:, max(j * pw - half, 0):j * pw + band - half] = True
    return hm, vm


def smooth_seams(img: Tensor, k: int, band: int = 8, long: int = 16, short: int = 2,
                 sigma: float = 5.0) -> Tensor:  # [B, C, H, W] -> same
    """Blur the seam bands of an assembled k×k patch image; pixels outside the bands are
    returned unchanged.  Horizontal seams use a ``long``-tall × ``short``-wide Gaussian (it
    crosses the seam), vertical seams the transposed one; where bands cross, the horizontal
    result is blurred again by the vertical kernel.  Even kernel sizes are applied centred
    (see :func:`_centred`)."""
    B, C, H, W = img.shape
    hm, vm = (m.to(img.device) for m in seam_masks(H, W, k, band))
    out = img
    for mask, (kh, kw) in ((hm, (long, short)), (vm, (short, long))):
        if not bool(mask.any()):
            continue
        ker = _centred(gaussian_kernel(kh, kw, sigma)).to(img)
        ph, pw = ker.shape[0] // 2, ker.shape[1] // 2
        ker = ker[None, None].expand(C, 1, *ker.shape)
        blurred = Fnn.conv2d(Fnn.pad(out, (pw, pw, ph, ph), mode="replicate"), ker, groups=C)
        out = torch.where(mask, blurred, out)
    return out


def smooth_seams_inplace(img: np.ndarray, k: int, band: int = 8, long: int = 16, short: int = 2,
                         sigma: float = 5.0) -> np.ndarray:  # [C, H, W] numpy, modified and returned
    """:func:`smooth_seams` on a [C, H, W] numpy array (or memmap), in place and strip by strip:
    memory is a few seam strips, not copies of the image.  Same result as :func:`smooth_seams`."""
    C, H, W = img.shape
    ph_, pw_ = _check((H, W), k)
    half = band // 2
    for axis, (kh, kw), step in ((1, (long, short), ph_), (2, (short, long), pw_)):
        ker = _centred(gaussian_kernel(kh, kw, sigma))
        mh, mw = ker.shape[0] // 2, ker.shape[1] // 2
        kt = ker[None, None].expand(C, 1, *ker.shape)
        n = H if axis == 1 else W
        results = []
        for s in range(1, k):
            a, b = max(s * step - half, 0), min(s * step + band - half, n)
            m = mh if axis == 1 else mw  # margin across the seam
            lo, hi = max(a - m, 0), min(b + m, n)
            strip = img[:, lo:hi] if axis == 1 else img[:, :, lo:hi]
            t = torch.from_numpy(np.ascontiguousarray(strip, np.float32))[None]
            if axis == 1:
                pad = (mw, mw, m - (a - lo), m - (hi - b))
            else:
                pad = (m - (a - lo), m - (hi - b), mh, mh)
            blurred = Fnn.conv2d(Fnn.pad(t, pad, mode="replicate"), kt.to(t), groups=C)[0].numpy()
            results.append((a, b, blurred))
        for a, b, blurred in results:  # all strips read the pre-pass image, then write
            if axis == 1:
                img[:, a:b] = blurred
            else:
                img[:, :, a:b] = blurred
    return img


def stream_patches(fn: Callable[[int, int, slice, slice], np.ndarray], size: tuple[int, int], k: int,
                   channels: int, out: np.ndarray | None = None, dtype=np.float32) -> np.ndarray:
    """Run ``fn(i, j, ys, xs)`` → patch [channels, ph, pw] for every patch and write it into
    ``out`` [channels, H, W] (a numpy array or memmap, created if None).  Nothing else is kept."""
    H, W = size
    ph, pw = _check(size, k)
    if out is None:
        out = np.zeros((channels, H, W), dtype)
    elif out.shape != (channels, H, W):
        raise LearnError(f"out must have shape {(channels, H, W)}; got {out.shape}")
    for i, j, ys, xs in patch_boxes(H, W, k):
        p = np.asarray(fn(i, j, ys, xs))
        if p.shape != (channels, ph, pw):
            raise LearnError(f"patch ({i}, {j}) has shape {p.shape}; expected {(channels, ph, pw)}")
        out[:, ys, xs] = p
    return out
