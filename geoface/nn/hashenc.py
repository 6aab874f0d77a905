"""Multiresolution hash encodings in pure torch (Müller et al. 2022, "Instant NGP").

Used by the texture networks (a 2D encoding of UV coordinates, 4K-texture paper) and by the
THGS audio module (a tri-plane encoding: three 2D encodings on the xy, yz and xz planes).

For level l = 0..L-1 the grid resolution is N_l = floor(N_min · b^l) with
b = exp((ln N_max − ln N_min) / (L − 1)).  A point x ∈ [0, 1]^d is scaled to x·N_l; the 2^d
corners of its grid cell are looked up in a table of T = 2^log2_table entries × F features,
directly (row-major index) when (N_l + 1)^d ≤ T, else through the spatial hash
h(c) = (⊕_i c_i · π_i) mod T with π = (1, 2654435761, 805459861); the corner features are
blended with d-linear weights.  Output: [..., L·F] (level-major).  Inputs outside [0, 1] are
clamped.  Tables start uniform in [−1e-4, 1e-4] as in the paper.

>>> enc = HashEncoding(dim=2, levels=4, features=2)     # doctest: +SKIP
>>> enc(torch.rand(10, 2)).shape                          # doctest: +SKIP
torch.Size([10, 8])
"""
from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from geoface.nn.errors import NNError

PRIMES = (1, 2654435761, 805459861)


def level_resolutions(levels: int, base_res: int, max_res: int) -> list[int]:
    """N_l = floor(N_min · b^l), b the growth factor that reaches ``max_res`` at the last level."""
    if levels == 1:
        return [int(base_res)]
    b = math.exp((math.log(max_res) - math.log(base_res)) / (levels - 1))
    return [int(math.floor(base_res * b**lvl + 1e-9)) for lvl in range(levels)]


def grid_index(corner: Tensor, res: int, table_size: int) -> Tensor:  # [..., d] int64 -> [...]
    """Table row of integer grid corners: dense row-major when the grid fits, else hashed."""
    d = corner.shape[-1]
    if (res + 1) ** d <= table_size:
        idx = torch.zeros_like(corner[..., 0])
        for i in range(d - 1, -1, -1):
            idx = idx * (res + 1) + corner[..., i]
        return idx
    h = torch.zeros_like(corner[..., 0])
    for i in range(d):
        h = h ^ (corner[..., i] * PRIMES[i])
    return h % table_size


def hash_encode(x: Tensor,  # [..., d] in [0, 1]
                tables: Tensor,  # [L, T, F]
                resolutions: list[int]) -> Tensor:  # -> [..., L*F]
    """Functional form of :class:`HashEncoding` (vectorised over points and corners)."""
    d = x.shape[-1]
    L, T, F = tables.shape
    x = x.clamp(0.0, 1.0)
    offs = torch.tensor([[(k >> i) & 1 for i in range(d)] for k in range(2 ** d)],
                        device=x.device)  # [2^d, d] corner offsets
    out = []
    for lvl, res in enumerate(resolutions):
        p = x * res
        c0 = torch.clamp(torch.floor(p), max=res - 1).to(torch.int64)  # [..., d]
        f = p - c0.to(p.dtype)  # in [0, 1]
        corners = c0[..., None, :] + offs  # [..., 2^d, d]
        w = torch.where(offs.bool(), f[..., None, :], 1 - f[..., None, :]).prod(-1)  # [..., 2^d]
        feats = tables[lvl][grid_index(corners, res, T)]  # [..., 2^d, F]
        out.append((w[..., None] * feats).sum(-2))
    return torch.cat(out, -1)


def hash_encode_reference(x: Tensor, tables: Tensor, resolutions: list[int]) -> Tensor:
    """Slow and obvious: one point, one level, one corner at a time (tests only)."""
    d = x.shape[-1]
    L, T, F = tables.shape
    flat = x.reshape(-1, d)
    rows = []
    for pt in flat:
        feats = []
        for lvl, res in enumerate(resolutions):
            acc = torch.zeros(F, dtype=tables.dtype)
            for k in range(2 ** d):
                w = torch.ones((), dtype=x.dtype)
                corner = []
                for i in range(d):
                    xi = min(max(float(pt[i]), 0.0), 1.0) * res
                    ci = min(math.floor(xi), res - 1)
                    bit = (k >> i) & 1
                    fi = pt[i].clamp(0, 1) * res - ci
                    w = w * (fi if bit else 1 - fi)
                    corner.append(ci + bit)
                if (res + 1) ** d <= T:
                    idx = 0
                    for i in range(d - 1, -1, -1):
                        idx = idx * (res + 1) + corner[i]
                else:
                    h = 0
                    for i in range(d):
                        h ^= corner[i] * PRIMES[i]
                    idx = h % T
                acc = acc + w * tables[lvl, idx]
            feats.append(acc)
        rows.append(torch.cat(feats))
    return torch.stack(rows).reshape(*x.shape[:-1], L * F)


class HashEncoding(nn.Module):
    """Learnable multiresolution hash encoding of points in [0, 1]^dim → [..., levels·features].

    Defaults follow the 4K-texture paper's UV encoding (L = 4 levels × F = 2 features = 8
    channels); ``base_res``/``max_res`` set the coarsest and finest grids, ``log2_table`` the
    table size per level.
    """

    def __init__(self, dim: int = 2, levels: int = 4, features: int = 2, log2_table: int = 16,
                 base_res: int = 16, max_res: int = 1024, init_scale: float = 1e-4, seed: int | None = None):
        super().__init__()
        if dim not in (1, 2, 3):
            raise NNError(f"dim must be 1, 2 or 3; got {dim}")
        if levels < 1 or features < 1 or not 1 <= log2_table <= 26:
            raise NNError(f"levels and features must be >= 1 and log2_table in 1..26; got "
                             f"levels={levels}, features={features}, log2_table={log2_table}")
        if not 1 <= base_res <= max_res:
            raise NNError(f"need 1 <= base_res <= max_res; got base_res={base_res}, max_res={max_res}")
        self.dim, self.levels, self.features = dim, levels, features
        self.resolutions = level_resolutions(levels, base_res, max_res)
        g = torch.Generator().manual_seed(seed) if seed is not None else None
        t = (torch.rand(levels, 2 ** log2_table, features, generator=g) * 2 - 1) * init_scale
        self.tables = nn.Parameter(t)

    @property
    def out_dim(self) -> int:
        return self.levels * self.features

    def forward(self, x: Tensor) -> Tensor:  # [..., dim] -> [..., out_dim]
        if x.shape[-1] != self.dim:
            raise NNError(f"expected points with {self.dim} coordinates; got shape {tuple(x.shape)}")
        return hash_encode(x.to(self.tables.dtype), self.tables, self.resolutions)


class TriPlaneHashEncoding(nn.Module):
    """THGS's tri-plane encoding: 2D hash encodings of the xy, yz and xz projections of points
    in a box, concatenated → [..., 3·levels·features].  ``bbox`` = (min xyz, max xyz)."""

    PLANES = ((0, 1), (1, 2), (0, 2))

    def __init__(self, bbox, levels: int = 8, features: int = 2, log2_table: int = 14,
                 base_res: int = 16, max_res: int = 512, seed: int | None = None):
        super().__init__()
        lo, hi = (torch.as_tensor(b, dtype=torch.float32).reshape(3) for b in bbox)
        if not bool((hi > lo).all()):
            raise NNError(f"bbox max must exceed min on every axis; got {lo.tolist()} .. {hi.tolist()}")
        self.register_buffer("lo", lo)
        self.register_buffer("hi", hi)
        self.planes = nn.ModuleList(
            HashEncoding(2, levels, features, log2_table, base_res, max_res,
                         seed=None if seed is None else seed + k) for k in range(3))

    @property
    def out_dim(self) -> int:
        return sum(p.out_dim for p in self.planes)

    def forward(self, x: Tensor) -> Tensor:  # [..., 3] world -> [..., 3·L·F]
        u = (x - self.lo.to(x.dtype)) / (self.hi - self.lo).to(x.dtype)
        return torch.cat([enc(u[..., list(ax)]) for enc, ax in zip(self.planes, self.PLANES)], -1)
