"""HFM-GS building blocks: positional encoding, MLPs, the crop encoder, key sampling and
inverse-distance spreading, the boundary loss and segregation density control
(:mod:`geoface.hfm`)."""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as Fnn
from torch import Tensor, nn

from geoface.splat.density import DensityConfig, DensityStrategy


# ----------------------------------------------------------------------------- building blocks
def posenc(x: Tensor, n_freqs: int) -> Tensor:
    """γ(x) = (x, sin(2^k π x), cos(2^k π x)), k < n_freqs; x roughly in [-1, 1]."""
    f = (2.0 ** torch.arange(n_freqs, dtype=x.dtype, device=x.device)) * math.pi
    a = x[..., None] * f  # [N, 3, F]
    return torch.cat([x, a.sin().flatten(-2), a.cos().flatten(-2)], -1)


def mlp(d_in: int, hidden: int, d_out: int, depth: int = 3, zero_last: bool = True) -> nn.Sequential:
    layers, d = [], d_in
    for _ in range(depth - 1):
        layers += [nn.Linear(d, hidden), nn.ReLU(inplace=True)]
        d = hidden
    last = nn.Linear(d, d_out)
    if zero_last:  # identity deformation at initialisation
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
    return nn.Sequential(*layers, last)


class DeformHeads(nn.Module):
    """(ΔX, log ΔS, ΔR) [n, 10] from one input by three MLPs, one per parameter, as eq. 2's
    MLP_X, MLP_S, MLP_R (each starting at the identity deformation)."""

    def __init__(self, d_in: int, hidden: int):
        super().__init__()
        self.x, self.s, self.r = mlp(d_in, hidden, 3), mlp(d_in, hidden, 3), mlp(d_in, hidden, 4)

    def forward(self, h: Tensor) -> Tensor:
        return torch.cat([self.x(h), self.s(h), self.r(h)], -1)


class ImageEncoder(nn.Module):
    """E_img: five stride-2 3×3 convolutions (crop² → (crop/32)²) with GroupNorm + SiLU, one
    multi-head self-attention layer over the cells (residual, LayerNorm), flatten, linear → θ.

    The crop follows the lower-face landmarks, so it no longer shows where the head is in the
    frame; the crop box (centre and side relative to the image, ``box`` [B, 3]) joins the
    flattened features before the last linear layer so that θ still carries the head's position."""

    def __init__(self, latent_dim: int = 128, width: int = 32, crop: int = 128):
        super().__init__()
        ch = [3, width, 2 * width, 4 * width, 4 * width, 4 * width]
        convs = []
        for a, b in zip(ch[:-1], ch[1:]):
            convs += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.GroupNorm(min(8, b), b), nn.SiLU()]
        self.convs = nn.Sequential(*convs)
        self.cells = (crop // 32) ** 2
        c = ch[-1]
        self.pos = nn.Parameter(torch.zeros(1, self.cells, c))
        self.attn = nn.MultiheadAttention(c, 4, batch_first=True)
        self.norm = nn.LayerNorm(c)
        self.out = nn.Linear(c * self.cells + 3, latent_dim)

    def forward(self, x: Tensor, box: Tensor | None = None) -> Tensor:  # [B, 3, crop, crop] in [0, 1] -> [B, latent]
        h = self.convs(x * 2 - 1)
        t = h.flatten(2).transpose(1, 2) + self.pos  # [B, cells, C]
        t = self.norm(t + self.attn(t, t, t, need_weights=False)[0])
        if box is None:
            box = x.new_tensor([[0.5, 0.5, 0.5]]).expand(len(x), 3)
        return self.out(torch.cat([t.flatten(1), (box - 0.5) * 4], 1))


def axis_angle_to_quat(w: Tensor) -> Tensor:  # [3] -> [4]
    ang = w.norm()
    half = 0.5 * ang
    k = torch.where(ang > 1e-8, torch.sin(half) / ang.clamp_min(1e-8), 0.5 - ang**2 / 48)
    return torch.cat([torch.cos(half)[None], w * k])


def farthest_point_sampling(P: Tensor, k: int, seed: int = 0) -> Tensor:
    """Indices of ``k`` points of ``P`` [N, 3] by farthest-point sampling (all when N ≤ k)."""
    n = len(P)
    if n <= k:
        return torch.arange(n, device=P.device)
    g = torch.Generator().manual_seed(seed)
    idx = torch.empty(k, dtype=torch.long, device=P.device)
    idx[0] = int(torch.randint(n, (1,), generator=g))
    d = ((P - P[idx[0]]) ** 2).sum(1)
    for i in range(1, k):
        idx[i] = torch.argmax(d)
        d = torch.minimum(d, ((P - P[idx[i]]) ** 2).sum(1))
    return idx


def inverse_distance_weights(P: Tensor, keys: Tensor, k: int = 8, eps: float = 1e-9) -> tuple[Tensor, Tensor]:
    """W_dist (eq. 10) as (neighbour index [N, k'], weight [N, k']): the k' = min(k, #keys)
    nearest key positions of each point of ``P``, weights 1/d normalised (rows sum to 1; a
    point that is a key gets weight ≈1 on itself)."""
    from scipy.spatial import cKDTree

    kk = min(k, len(keys))
    d, j = cKDTree(keys.detach().cpu().numpy()).query(P.detach().cpu().numpy(), k=kk)
    d = np.asarray(d, dtype=np.float64).reshape(len(P), kk)
    j = np.asarray(j).reshape(len(P), kk)
    w = 1.0 / (d + eps)
    w /= w.sum(1, keepdims=True)
    return torch.as_tensor(j, device=P.device), torch.as_tensor(w, dtype=P.dtype, device=P.device)


def boundary_loss(y: Tensor, upper: Tensor, y_t: float, d: float = 0.0) -> Tensor:
    """Eq. 11–12: mean ReLU(y_t + d − y) over the upper Gaussians + mean ReLU(y − y_t + d) over
    the lower: with the margin ``d`` > 0 each half is held a distance d from the plane."""
    zero = y.new_zeros(())
    lu = Fnn.relu(y_t + d - y[upper]).mean() if bool(upper.any()) else zero
    ll = Fnn.relu(y[~upper] - y_t + d).mean() if bool((~upper).any()) else zero
    return lu + ll


class SegregationStrategy(DensityStrategy):
    """3DGS density control with HFM-GS's Algorithm 1: a split child is dropped when it crosses
    y_t by more than ``margin``; ``upper`` [N] bool (which half each Gaussian belongs to) follows
    clones, splits and prunes."""

    def __init__(self, cfg: DensityConfig | None, scene_extent: float, y_split: float, margin: float,
                 upper: Tensor):
        super().__init__(cfg, scene_extent)
        self.y_split, self.margin = float(y_split), float(margin)
        self.upper = upper.clone().bool()
        self.dropped = 0

    def filter_split(self, gaussians, parent_idx, child_params):
        y = child_params["means"][:, 1]
        up = self.upper.to(parent_idx.device)[parent_idx]
        keep = torch.where(up, y >= self.y_split - self.margin, y <= self.y_split + self.margin)
        self.dropped += int((~keep).sum())
        return keep

    def on_added(self, gaussians, src_idx, n_new):
        self.upper = torch.cat([self.upper, self.upper[src_idx.to(self.upper.device)]])

    def on_pruned(self, gaussians, keep):
        self.upper = self.upper[keep.to(self.upper.device)]
