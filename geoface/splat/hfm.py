"""HFM-GS: half-face-mapping Gaussian avatars for real-time HMD removal (Wang et al., TVCG 2025).

A person is registered from a short unoccluded video; afterwards, each frame of a video in which
a headset hides the upper face is restored from the visible lower face alone:

1. **Latent** θ = E_img(lower-face crop): five stride-2 convolutions (128² → 4²) and one
   self-attention layer over the 16 cells, flattened to a 128-d code.
2. **Canonical Gaussians** from the registration head mesh (one per vertex), split by the
   plane y = y_t into an upper set U (y > y_t) and a lower set L.
3. **Lower face** (eq. 2): for i ∈ L, ΔX_i, ΔS_i, ΔR_i = MLP_X, MLP_S, MLP_R(γ(x_i), θ) with
   γ the NeRF frequency embedding of the canonical position.
4. **Gaussian mapping** (eq. 3–4): φ_i = MLP_gm(γ(x_i)) ∈ R^10 and W_gm = row-softmax(φ_U φ_Lᵀ),
   how much each upper Gaussian follows each lower one.
5. **Parameter mapping** (eq. 6–7): lower features f_L = MLP_pm(γ(x_L), p̂_L) of the lower
   deformations p_L = (ΔX, log ΔS, ΔR); upper features f_U = W_gm f_L; upper deformations
   (eq. 5/7) p_U = MLP_mapping(γ(x_U), f_U). p̂_L = p_L / RMS is each channel divided by its
   running RMS over training (``map_norm``, a buffer saved with the model; like batch norm's
   running statistics, without centring): the networks start at the identity, so p_L grows from
   0 to a few hundredths, and read raw it stayed a small part of MLP_pm's input next to the O(1)
   position embedding; on the synthetic head the upper face then hardly followed the lower one.
   The mapping reads p_L detached (``detach_lower``, default on): the upper-face loss then trains
   the mapping networks but not the lower face's. On the synthetic videos, detaching gained Full
   0.4 dB in the occluded region (five of six runs) and 0.2 dB on the whole face (six of six)
   over training the lower networks through the mapping. Detached, the encoder learns from the
   lower face alone; ``map_latent_grad`` lets the upper-face loss train θ through frozen copies of
   the eq.-2 networks (off: on two further heads it changed the occluded region by +0.05 and
   −0.47 dB). MLP_mapping reads f_U standardised per channel by its running mean and standard
   deviation (``feat_norm``, buffers saved with the model): f_U is mostly a constant (the average
   of MLP_pm over the key positions) and moves with the expression ~20× less than θ moves the
   eq.-2 networks' input (regression on the eyes' closing, synthetic head), so MLP_mapping
   learned the lids' closing in a smile too slowly to show it within training. MLP_mapping is
   three MLPs on the same input, one each for ΔX, log ΔS and ΔR (``mapping_heads=3``), as eq. 2
   decodes the lower face: one MLP for all ten outputs gave the upper face a third of the hidden
   units that the variant without the mapping spends on it, and on the synthetic head it fit the
   brows' raise and the lids' closing worse than that variant even on the training frames (mean
   squared error on the 12 strongest surprise / smile frames, data seed 1: 3.0 / 1.5 ·10⁻⁴
   against 2.0 / 1.1; with three heads 2.9 / 1.1). At the end of training both normalisations'
   statistics are recomputed as plain means over the registration frames with the final
   weights (:meth:`HFMModel.refit_statistics`).
6. **Global pose** (eq. 8): (ω, τ) = MLP_pose(θ), a rotation exp(ω) about the head centre and a
   translation applied to every Gaussian after the local deformation. Where the video folder has
   the tracked head pose (``head_poses.npz``: a face tracker in registration, the headset's own
   6-DoF tracking in use), it is applied after that, and the MLP learns the residual. Without
   it the pose has to be read from the lower-face crop alone: on the synthetic videos (yaw ±8°)
   training then stalls at an L1 loss near 0.05, against 0.007 for a still head.
7. **Correlation-weight sampling** (eq. 9–10): the mapping runs between 512 upper and 512 lower
   *key* Gaussians only — upper keys by farthest-point sampling of the canonical positions,
   lower keys 512 drawn without replacement with probability proportional to their correlation
   weight Σ_u W_gm[u, l] towards the upper keys (``lower_keys="sample"``, the default; ``"top"``
   takes the 512 largest, which lets an early, still uninformative W_gm lock the keys onto one
   region — on the synthetic head, the neck, away from the mouth that carries the expression) —
   and every upper Gaussian takes the inverse-distance average (W_dist, k nearest upper
   keys, rows sum to 1) of the keys' upper features f_U, which MLP_mapping turns into its
   deformation at its own position (``upsample="features"``); ``"params"`` averages the keys'
   deformations instead. Upper keys lie ~12 mm apart on the synthetic head, and averaging
   deformations moves a lid, the eye under it and the brow above it alike, so the eyes could not
   close in a smile. Cost O(512²) for the mapping plus one MLP per upper Gaussian (like the
   eq.-2 networks per lower one) instead of O(|U|·|L|). Keys are refreshed after every
   densification and every ``key_every`` steps.
8. **Composition** (eq. 1): X + ΔX, S·ΔS, R ⊗ ΔR; then the global pose.

**Gaussian segregation** (Algorithm 1 and eq. 11–12): density control where a split child that
crosses y_t by more than ``margin`` (an upper parent's child below y_t − m, a lower parent's
above y_t + m) is dropped, and ReLU boundary losses Σ_U ReLU(y_t − y) + Σ_L ReLU(y − y_t) (means
over each set) on the canonical positions keep the halves apart.

**Loss** (eq. 13): (1 − λ_rgb)·L1 + λ_rgb·D-SSIM + λ_vgg·L_vgg + λ_split·L_split with
λ_rgb = 0.4, λ_vgg = 0.1, λ_split = 0.01. L_vgg compares VGG-16 features (relu1_2, relu2_2,
relu3_3) and needs local weights (``vgg_weights``: a safetensors/torch file of torchvision's
``vgg16().features`` state dict, keys ``features.N.weight``); without them it is left out and
training says so.

**Training.** One frame per step, Adam. The first ``warmup`` (20%) of the steps train the
Gaussians alone (the networks start at the identity deformation); the networks then train at
``lr_nets`` = 2e-4 with Adam's usual ε. At 1e-3 (and the 3DGS ε = 1e-15 for everything) the
deformation MLPs lost most of their ReLU units within a few hundred steps and the encoder
collapsed θ to a near constant for some model seeds: the avatar then never followed an
expression (upper-face Gaussians moved by 1e-6 m across frames) and the ablation comparison
measured which seeds happened to escape. The saved model is the exponential moving average of
all weights (Gaussians and networks; ``ema`` = 0.99 per step, bias-corrected, :class:`WeightAverage`)
over the steps after density control stops. With one frame per step the weights never settle:
continuing two trained models (Full and the variant without the mapping) for 300 steps on the
synthetic head, checkpoints 25 steps apart scored 33.5–35.6 dB in the occluded region (SD 0.63),
so a model's score was mostly the luck of its last step, and so was every comparison between
variants; a moving average of the same steps (decay 0.98) scored 34.4–35.9 dB (SD 0.39), 0.6 dB
higher on average.

Ablations (``HFMConfig``): ``global_pose=False`` (no pose MLP), ``gaussian_mapping=False`` (no
Gaussian & feature mapping: the upper face is deformed from θ by the lower face's networks of
eq. 2, one deformation field over the whole head; ``unmapped_upper="separate"`` gives it its own
MLP instead, a stronger baseline than the paper's ablation with more weights than the mapping's),
``feature_mapping=False`` (W_gm maps the lower deformations p_L themselves, no MLP_pm),
``sampling=False`` (the mapping over all Gaussians).
"""
from __future__ import annotations

import contextlib
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as Fnn
from torch import Tensor, nn

from geoface.splat.density import DensityConfig, DensityStrategy, make_optimizer
from geoface.splat.errors import SplatError
from geoface.splat.gaussians import Gaussians, GaussianTensors, quat_mul, quat_to_rotmat, rotmat_to_quat_torch

__all__ = ["HFMConfig", "HFMModel", "ImageEncoder", "SegregationStrategy", "WeightAverage", "select_keys",
           "inverse_distance_weights", "farthest_point_sampling", "boundary_loss", "VGGPerceptual",
           "expression_motion", "train_hfm", "load_hfm", "remove_hmd", "evaluate_hmd", "hmd_metrics", "ABLATIONS"]

ABLATIONS = {
    "full": {},
    "no_global_pose": {"global_pose": False},
    "no_gaussian_feature_mapping": {"gaussian_mapping": False},
    "no_gaussian_feature_mapping_separate": {"gaussian_mapping": False, "unmapped_upper": "separate"},
    "no_feature_mapping": {"feature_mapping": False},
    "no_sampling": {"sampling": False},
}


@dataclass
class HFMConfig:
    """Model, loss and training settings (defaults: the paper's where it gives them)."""

    latent_dim: int = 128
    crop: int = 128
    enc_width: int = 32
    pos_freqs: int = 6
    hidden: int = 128
    emb_dim: int = 10          # MLP_gm embeddings
    feat_dim: int = 32         # MLP_pm features
    n_keys: int = 512          # key Gaussians per half
    k_upsample: int = 8        # nearest upper keys in W_dist
    mapping_heads: int = 3     # MLP_mapping as three MLPs, one each for ΔX, ΔS, ΔR as in eq. 2 (3), or one for all (1)
    upsample: str = "features"  # W_dist spreads the keys' mapped features ("features") or their deformations ("params")
    y_split: float | None = None   # y_t (world metres); None: the registration folder's meta.json
    margin: float = 0.004      # m of Algorithm 1 (metres)
    global_pose: bool = True
    gaussian_mapping: bool = True
    feature_mapping: bool = True
    sampling: bool = True
    unmapped_upper: str = "shared"  # without the mapping: upper face by MLP_X/S/R ("shared") or its own MLP
    lower_keys: str = "sample"  # "sample" (∝ correlation weight) or "top" (largest weights)
    detach_lower: bool = True   # the mapping reads the lower deformations without training them
    map_latent_grad: bool = False  # with detach_lower: the upper-face loss still trains θ (the encoder)
    map_norm: bool = True       # the mapping reads p_L / running RMS (per channel) instead of raw p_L
    map_norm_momentum: float = 0.02
    feat_norm: bool = True      # MLP_mapping reads f_U standardised per channel by running statistics
    lambda_rgb: float = 0.4
    lambda_vgg: float = 0.1
    lambda_split: float = 0.01
    vgg_weights: str | None = None
    iters: int = 2000
    warmup: float = 0.2        # fraction of iters that trains the Gaussians alone (static warm-up)
    lr_nets: float = 2e-4     # 1e-3 (batch of one frame) kills ReLU units and collapses θ to a constant
    ema: float = 0.99          # the saved model averages the weights over the last steps (decay per step; 0: last step)
    lr_means: float = 1.6e-4   # × head size (3DGS, scene-scaled)
    key_every: int = 100
    densify: bool = True
    init_opacity: float = 0.5
    seed: int = 0
    threads: int | None = None

    def __post_init__(self):
        for name in ("latent_dim", "crop", "enc_width", "hidden", "emb_dim", "feat_dim", "n_keys",
                     "k_upsample", "iters", "key_every"):
            if int(getattr(self, name)) < 1:
                raise SplatError(f"HFMConfig.{name} must be >= 1; got {getattr(self, name)!r}")
        if self.crop % 32:
            raise SplatError(f"HFMConfig.crop must be a multiple of 32 (five stride-2 convolutions); got {self.crop}")
        if self.mapping_heads not in (1, 3):
            raise SplatError(f"HFMConfig.mapping_heads must be 1 or 3; got {self.mapping_heads!r}")
        if self.unmapped_upper not in ("shared", "separate"):
            raise SplatError(f"HFMConfig.unmapped_upper must be 'shared' or 'separate'; got {self.unmapped_upper!r}")
        if self.upsample not in ("params", "features"):
            raise SplatError(f"HFMConfig.upsample must be 'params' or 'features'; got {self.upsample!r}")
        if self.lower_keys not in ("sample", "top"):
            raise SplatError(f"HFMConfig.lower_keys must be 'sample' or 'top'; got {self.lower_keys!r}")
        if self.margin < 0:
            raise SplatError(f"HFMConfig.margin must be >= 0; got {self.margin}")
        if not 0 < self.map_norm_momentum <= 1:
            raise SplatError(f"HFMConfig.map_norm_momentum must be in (0, 1]; got {self.map_norm_momentum}")
        if not 0 <= self.warmup < 1:
            raise SplatError(f"HFMConfig.warmup is a fraction of iters in [0, 1); got {self.warmup}")
        if not 0 <= self.ema < 1:
            raise SplatError(f"HFMConfig.ema is a decay per step in [0, 1); got {self.ema}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where: str = "HFM config") -> "HFMConfig":
        from geoface.nn.config import config_from_dict

        from .errors import ModelFolderError

        return config_from_dict(cls, d, where=where, error=ModelFolderError)


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


def boundary_loss(y: Tensor, upper: Tensor, y_t: float) -> Tensor:
    """Eq. 11–12: mean ReLU(y_t − y) over the upper Gaussians + mean ReLU(y − y_t) over the lower."""
    zero = y.new_zeros(())
    lu = Fnn.relu(y_t - y[upper]).mean() if bool(upper.any()) else zero
    ll = Fnn.relu(y[~upper] - y_t).mean() if bool((~upper).any()) else zero
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


# ----------------------------------------------------------------------------- the model
class HFMModel(nn.Module):
    """Canonical Gaussians + E_img + the deformation and mapping networks (module doc)."""

    def __init__(self, gaussians: Gaussians, cfg: HFMConfig, y_split: float, center=None, scale=None):
        super().__init__()
        self.cfg = cfg
        self.gaussians = gaussians
        self.y_split = float(y_split)
        P = gaussians.means.detach()
        c = P.mean(0) if center is None else torch.as_tensor(center, dtype=P.dtype)
        s = (P - c).abs().max() if scale is None else torch.as_tensor(scale, dtype=P.dtype)
        self.register_buffer("center", c.clone())
        self.register_buffer("scale", s.clone().reshape(()))
        e = 3 + 6 * cfg.pos_freqs
        L, H = cfg.latent_dim, cfg.hidden
        self.encoder = ImageEncoder(L, cfg.enc_width, cfg.crop)
        self.mlp_x, self.mlp_s, self.mlp_r = mlp(e + L, H, 3), mlp(e + L, H, 3), mlp(e + L, H, 4)
        if cfg.gaussian_mapping:
            self.mlp_gm = mlp(e, 64, cfg.emb_dim, zero_last=False)
            f_in = cfg.feat_dim if cfg.feature_mapping else 10
            if cfg.feature_mapping:
                self.mlp_pm = mlp(e + 10, 64, cfg.feat_dim, zero_last=False)
            self.mlp_mapping = mlp(e + f_in, H, 10) if cfg.mapping_heads == 1 else DeformHeads(e + f_in, H)
        elif cfg.unmapped_upper == "separate":
            self.mlp_up = mlp(e + L, H, 10)
        if cfg.global_pose:
            self.mlp_pose = mlp(L, 64, 6)
        if cfg.gaussian_mapping and cfg.map_norm:
            # running mean square of each lower deformation channel (bias-corrected EMA over steps)
            self.register_buffer("p_ms", torch.zeros(10))
            self.register_buffer("p_steps", torch.zeros(()))
        if cfg.gaussian_mapping and cfg.feat_norm:
            # running mean and mean square of each upper feature channel (bias-corrected EMA)
            self.register_buffer("f_mean", torch.zeros(f_in))
            self.register_buffer("f_ms", torch.zeros(f_in))
            self.register_buffer("f_steps", torch.zeros(()))
        self._refit: str | None = None  # inside refit_statistics: which statistics it averages
        self.keys_u: Tensor | None = None
        self.keys_l: Tensor | None = None
        self.wdist: tuple[Tensor, Tensor] | None = None

    # ------------------------------------------------------------- halves and keys
    def upper_mask(self) -> Tensor:
        return self.gaussians.means.detach()[:, 1] > self.y_split

    def embed(self, X: Tensor) -> Tensor:
        return posenc((X - self.center) / self.scale, self.cfg.pos_freqs)

    @torch.no_grad()
    def refresh_keys(self) -> None:
        """Pick the 512 + 512 key Gaussians and W_dist (correlation-weight sampling, eq. 9–10)."""
        if not (self.cfg.gaussian_mapping and self.cfg.sampling):
            self.keys_u = self.keys_l = self.wdist = None
            return
        up = self.upper_mask()
        iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
        X = self.gaussians.means.detach()
        ku, kl = select_keys(self, X, iu, il, self.cfg.n_keys, self.cfg.seed, self.cfg.lower_keys)
        self.keys_u, self.keys_l = ku, kl
        j, w = inverse_distance_weights(X[iu], X[ku], self.cfg.k_upsample)
        self.wdist = (j, w)
        self._keys_for = (len(X), iu, il)

    def _keys_valid(self, n, iu, il) -> bool:
        if self.keys_u is None:
            return False
        m, ju, jl = self._keys_for
        return m == n and torch.equal(ju, iu) and torch.equal(jl, il)

    # ------------------------------------------------------------- forward
    def lower_params(self, eX: Tensor, theta: Tensor, frozen: bool = False) -> Tensor:
        """[n, 10] eq.-2 deformations; ``frozen``: through the networks' weights detached (the
        result's gradient reaches θ and the positions, not MLP_X/S/R)."""
        h = torch.cat([eX, theta.expand(len(eX), -1)], -1)
        if frozen:
            def run(m):
                return torch.func.functional_call(m, {k: v.detach() for k, v in m.named_parameters()}, (h,))
        else:
            def run(m):
                return m(h)
        return torch.cat([run(self.mlp_x), run(self.mlp_s), run(self.mlp_r)], -1)

    def _mapping_input(self, p: Tensor, idx: Tensor, E: Tensor, theta: Tensor) -> tuple[Tensor, bool]:
        """The lower deformations the mapping reads at ``idx`` and whether to detach them: with
        ``map_latent_grad`` they are recomputed through frozen eq.-2 networks, so the upper-face
        loss trains θ but (as with ``detach_lower``) not the lower face's networks."""
        if self.cfg.detach_lower and self.cfg.map_latent_grad and p.requires_grad:  # False under no_grad
            return self.lower_params(E[idx], theta, frozen=True), False
        return p[idx], self.cfg.detach_lower

    def w_gm(self, eU: Tensor, eL: Tensor) -> Tensor:
        """W_gm = row-softmax(φ_U φ_Lᵀ) [|U|, |L|] from embedded positions (eq. 3–4)."""
        return torch.softmax(self.mlp_gm(eU) @ self.mlp_gm(eL).T, -1)

    @torch.no_grad()
    def _running_stats(self, steps: Tensor, bufs: tuple[Tensor, ...], values: tuple[Tensor, ...] | None):
        """Per-channel running statistics kept in the buffers ``bufs``: a bias-corrected EMA over
        steps (momentum ``map_norm_momentum``, step count ``steps``). Folds in ``values`` (one per
        buffer) when given, then returns the corrected estimates, or None before the first step.
        Inside :meth:`refit_statistics` the values are averaged with equal weights instead."""
        m = self.cfg.map_norm_momentum
        if values is not None:
            w = 1 / (float(steps) + 1) if self._refit is not None else m
            for b, v in zip(bufs, values):
                b.mul_(1 - w).add_(w * v)
            steps.add_(1)
        if float(steps) == 0:
            return None
        corr = 1 - (1 - m) ** steps
        return tuple(b / corr for b in bufs)

    def lower_rms(self, pL: Tensor, update: bool) -> Tensor:
        """[10] running RMS of the lower deformation channels, ``update``d by ``pL`` (in training,
        once the networks train; frozen otherwise and saved with the model). Without it (module
        doc, item 5) the upper deformations of a trained Full model varied 26× less across the
        synthetic frames than those of the variant that maps p_L itself."""
        st = self._running_stats(self.p_steps, (self.p_ms,), (pL.detach().pow(2).mean(0),) if update else None)
        if st is None:  # no statistics yet (an untrained model): p_L as it is
            return torch.ones_like(self.p_ms)
        return st[0].sqrt() + 1e-6

    def map_features(self, eU: Tensor, eL: Tensor, pL: Tensor, detach: bool | None = None) -> Tensor:
        """Upper features f_U = W_gm f_L from lower deformations (eq. 3–4, 6), dense over the given
        sets (rows of W_gm in chunks, so |U|·|L| never has to fit at once). ``detach`` (default
        ``detach_lower``): read ``pL`` without passing gradients back into it."""
        update = self._updates_statistics(pL, "p")
        if self.cfg.detach_lower if detach is None else detach:  # upper-face errors cannot reshape the lower face
            pL = pL.detach()
        if self.cfg.map_norm:
            pL = pL / self.lower_rms(pL, update)
        fL = self.mlp_pm(torch.cat([eL, pL], -1)) if self.cfg.feature_mapping else pL
        chunk = max(1, int(2**26 // max(len(eL), 1)))
        return torch.cat([self.w_gm(eU[i:i + chunk], eL) @ fL for i in range(0, len(eU), chunk)])

    def standardise_features(self, fU: Tensor) -> Tensor:
        """``feat_norm``: f_U minus its running mean, over its running standard deviation, per
        channel (updated in training once the networks train; frozen otherwise and saved with the
        model). f_U is mostly a constant (the average of MLP_pm over positions) plus a smaller
        part that follows the expression; standardised, that part reaches MLP_mapping at unit
        scale per channel (module doc, item 5)."""
        if not self.cfg.feat_norm:
            return fU
        f = fU.detach()
        st = self._running_stats(self.f_steps, (self.f_mean, self.f_ms),
                                 (f.mean(0), f.pow(2).mean(0)) if self._updates_statistics(fU, "f") else None)
        if st is None:
            return fU
        mean, ms = st
        # floor: a channel that barely varies is scaled up at most tenfold against its RMS
        return (fU - mean) / ((ms - mean.pow(2)).clamp_min(0) + 0.01 * ms + 1e-12).sqrt()

    def _updates_statistics(self, x: Tensor, which: str) -> bool:
        """Whether this pass folds ``x`` into the running statistics ``which`` ("p": map_norm's,
        "f": feat_norm's): in training once the networks train (not during the static warm-up,
        where ``x`` carries no gradient); inside :meth:`refit_statistics`, in that statistics' pass."""
        return (self.training and x.requires_grad) if self._refit is None else self._refit == which

    @torch.no_grad()
    def refit_statistics(self, crops: Tensor, boxes: Tensor | None = None) -> None:
        """Recompute the running statistics of ``map_norm`` and ``feat_norm`` as plain means over
        the frames ``crops`` [T, 3, crop, crop] (crop boxes ``boxes`` [T, 3]) with the current
        weights: first those of p_L, then, reading p_L by them, those of f_U (as SWA recomputes
        batch-norm statistics for averaged weights). In training the statistics follow the
        weights as an EMA over the last ~50 frames, so they are noisy, and they belong to the
        last steps' weights rather than to averaged ones; a channel of f_U that barely varies is
        divided by its small deviation, which magnifies any offset in its mean."""
        if not self.cfg.gaussian_mapping:
            return
        passes = [("p", self.p_steps, (self.p_ms,))] if self.cfg.map_norm else []
        if self.cfg.feat_norm:
            passes.append(("f", self.f_steps, (self.f_mean, self.f_ms)))
        try:
            for mode, steps, bufs in passes:
                for b in bufs:
                    b.zero_()
                steps.zero_()
                self._refit = mode
                for t in range(len(crops)):
                    self(crops[t:t + 1], None if boxes is None else boxes[t:t + 1])
                steps.fill_(1e6)  # the EMA's bias correction is then exactly 1
        finally:
            self._refit = None

    def map_params(self, eU: Tensor, eL: Tensor, pL: Tensor, detach: bool | None = None) -> Tensor:
        """Upper deformations p_U = MLP_mapping(γ(x_U), W_gm f_L) (eq. 3–7; ``map_features``)."""
        return self.mlp_mapping(torch.cat([eU, self.standardise_features(self.map_features(eU, eL, pL, detach))], -1))

    def map_keys(self, E: Tensor, iu: Tensor, pK: Tensor, detach: bool | None = None) -> Tensor:
        """Deformations [|U|, 10] of the upper Gaussians ``iu`` by the mapping between the key
        Gaussians (eq. 9–10; ``refresh_keys`` first), ``pK`` the lower keys' deformations and ``E``
        the embedded positions of all Gaussians. W_dist spreads over the upper Gaussians either
        the upper keys' deformations (``upsample="params"``) or their mapped features f_U, which
        MLP_mapping then turns into a deformation at each upper Gaussian's own position
        (``"features"``): keys lie ~12 mm apart on the synthetic head, so spreading deformations
        blurs an eyelid's closing into the brow and cheek around it."""
        j, w = self.wdist
        if self.cfg.upsample == "features":
            fk = self.standardise_features(self.map_features(E[self.keys_u], E[self.keys_l], pK, detach))
            return self.mlp_mapping(torch.cat([E[iu], (fk[j] * w[..., None]).sum(1)], -1))
        pk = self.map_params(E[self.keys_u], E[self.keys_l], pK, detach)
        return (pk[j] * w[..., None]).sum(1)

    def deform(self, theta: Tensor, head_pose=None) -> GaussianTensors:
        """The Gaussians for latent ``theta`` [1, latent] (eq. 1–10), then the tracked rigid head
        pose ``head_pose`` = (R [3, 3], t [3], pivot [3]) when given (X' = R (X − pivot) + pivot + t);
        the global pose MLP is then the residual the tracker missed."""
        g = self.gaussians
        X = g.means
        n = len(X)
        up = self.upper_mask()
        iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
        E = self.embed(X)
        one_field = not self.cfg.gaussian_mapping and self.cfg.unmapped_upper == "shared"
        if one_field:  # the eq.-2 networks deform both halves
            p = self.lower_params(E, theta)
        else:
            p = X.new_zeros(n, 10)
            p[il] = self.lower_params(E[il], theta)
        if len(iu) and not one_field:
            if not self.cfg.gaussian_mapping:
                p[iu] = self.mlp_up(torch.cat([E[iu], theta.expand(len(iu), -1)], -1))
            elif len(il) == 0:
                pass
            elif self.cfg.sampling:
                if not self._keys_valid(n, iu, il):
                    self.refresh_keys()
                p[iu] = self.map_keys(E, iu, *self._mapping_input(p, self.keys_l, E, theta))
            else:
                p[iu] = self.map_params(E[iu], E[il], *self._mapping_input(p, il, E, theta))
        dX, dlogS, dq = p[:, :3], p[:, 3:6], p[:, 6:]
        means = X + dX * self.scale * 0.1
        log_scales = g.log_scales + dlogS
        one = torch.tensor([1.0, 0, 0, 0], dtype=X.dtype, device=X.device)
        quats = quat_mul(g.quats / g.quats.norm(dim=-1, keepdim=True), one + dq)
        if self.cfg.global_pose:
            pose = self.mlp_pose(theta)[0]
            qg = axis_angle_to_quat(pose[:3])
            R = quat_to_rotmat(qg[None])[0]
            means = (means - self.center) @ R.T + self.center + pose[3:] * self.scale * 0.1
            quats = quat_mul(qg[None].expand(n, 4), quats)
        if head_pose is not None:
            R, t, piv = (torch.as_tensor(np.asarray(a), dtype=X.dtype, device=X.device) for a in head_pose)
            means = (means - piv) @ R.T + piv + t
            quats = quat_mul(rotmat_to_quat_torch(R[None]).expand(n, 4), quats)
        return GaussianTensors(means, log_scales, quats, g.opacity_logits, g.colors)

    def forward(self, crop: Tensor, box: Tensor | None = None, head_pose=None) -> GaussianTensors:
        return self.deform(self.encoder(crop, box), head_pose)


@torch.no_grad()
def select_keys(model: HFMModel, X: Tensor, iu: Tensor, il: Tensor, n_keys: int, seed: int = 0,
                lower: str = "sample"):
    """Key Gaussians (global indices, sorted): ``n_keys`` upper by farthest-point sampling,
    ``n_keys`` lower by their correlation weight c_l = Σ_u softmax_l(φ_u·φ_l) over the upper keys:
    drawn without replacement with probability ∝ c_l (``lower="sample"``, seeded by ``seed``) or
    the ``n_keys`` largest (``"top"``). All of a half when it has fewer."""
    ku = iu[farthest_point_sampling(X[iu], n_keys, seed)]
    if len(il) <= n_keys:
        return ku, il.clone()
    E = model.embed(X)
    corr = model.w_gm(E[ku], E[il]).sum(0)  # correlation weight of each lower Gaussian
    if lower == "top":
        pick = torch.topk(corr, n_keys).indices
    elif lower == "sample":
        gen = torch.Generator().manual_seed(int(seed))
        pick = torch.multinomial(corr.double().cpu(), n_keys, replacement=False, generator=gen).to(il.device)
    else:
        raise SplatError(f"lower keys: 'sample' or 'top', not {lower!r}")
    return ku, il[pick.sort().values]


# ----------------------------------------------------------------------------- VGG perceptual
_VGG16 = [64, 64, "M", 128, 128, "M", 256, 256, 256]  # up to relu3_3


class VGGPerceptual(nn.Module):
    """L1 between VGG-16 features (relu1_2, relu2_2, relu3_3) of ImageNet-normalised images.

    ``weights``: a local file (safetensors, or a torch state dict read with weights_only=True)
    holding torchvision's ``vgg16().features`` parameters (``features.N.weight``/``.bias`` or
    ``N.weight``); nothing is downloaded."""

    def __init__(self, weights):
        super().__init__()
        layers, c = [], 3
        for v in _VGG16:
            if v == "M":
                layers.append(nn.MaxPool2d(2))
            else:
                layers += [nn.Conv2d(c, v, 3, padding=1), nn.ReLU(inplace=False)]
                c = v
        self.features = nn.Sequential(*layers)
        self.taps = {3, 8, 15}
        sd = _load_state(weights)
        sd = {k[len("features."):] if k.startswith("features.") else k: v for k, v in sd.items()}
        own = self.features.state_dict()
        missing = [k for k in own if k not in sd]
        if missing:
            raise SplatError(f"{weights}: not VGG-16 feature weights (missing {missing[:3]})")
        try:
            self.features.load_state_dict({k: sd[k] for k in own})
        except RuntimeError as e:
            raise SplatError(f"{weights}: VGG-16 weights of the wrong shape ({str(e).splitlines()[0]})") from None
        self.requires_grad_(False)
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1))

    def forward(self, a: Tensor, b: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1]
        x = torch.cat([a, b]).sub(self.mean).div(self.std)
        loss = x.new_zeros(())
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in self.taps:
                fa, fb = x.chunk(2)
                loss = loss + (fa - fb).abs().mean()
        return loss


def _load_state(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise SplatError(f"{path}: no such weights file")
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file
            return load_file(str(path))
        sd = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as e:  # corrupt or not a weights file
        raise SplatError(f"{path}: cannot read weights ({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None
    if not isinstance(sd, dict):
        raise SplatError(f"{path}: not a state dict")
    return sd


# ----------------------------------------------------------------------------- training
class WeightAverage:
    """Exponential moving average of a module's parameters (Polyak averaging): ``update`` after
    each optimiser step folds the current values in with weight 1 − ``decay``; ``copy_to`` writes
    the bias-corrected averages into the module (the updates' values weighted by decay^age, over
    the updates made so far: a short run averages what it has). The parameters must keep their
    shapes while it runs (start it after density control has stopped adding and removing Gaussians)."""

    def __init__(self, module: nn.Module, decay: float):
        if not 0 <= decay < 1:
            raise SplatError(f"weight average decay must be in [0, 1); got {decay}")
        self.decay = float(decay)
        self.avg = {n: torch.zeros_like(p.detach()) for n, p in module.named_parameters()}
        self.steps = 0

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        for n, p in module.named_parameters():
            a = self.avg[n]
            if a.shape != p.shape:
                raise SplatError(f"weight average: {n} changed shape {tuple(a.shape)} -> {tuple(p.shape)}")
            a.mul_(self.decay).add_(p.detach(), alpha=1 - self.decay)
        self.steps += 1

    @contextlib.contextmanager
    def applied(self, module: nn.Module):
        """The averages in ``module`` inside the block, its own weights back afterwards."""
        with torch.no_grad():
            own = {n: p.detach().clone() for n, p in module.named_parameters()}
        self.copy_to(module)
        try:
            yield module
        finally:
            with torch.no_grad():
                for n, p in module.named_parameters():
                    p.copy_(own[n])

    @torch.no_grad()
    def copy_to(self, module: nn.Module) -> None:
        if self.steps == 0:
            raise SplatError("weight average: no update yet")
        corr = 1 - self.decay ** self.steps
        for n, p in module.named_parameters():
            p.copy_(self.avg[n] / corr)


def _frames_tensors(video, crop):
    imgs = torch.tensor(video.frames, dtype=torch.float32)
    crops = torch.tensor(video.crops(crop), dtype=torch.float32)
    return imgs, crops, torch.tensor(video.boxes())


def _pose(video, t):
    """Frame ``t``'s tracked head pose (R, t, pivot) or None."""
    if video.poses is None:
        return None
    R, tr, piv = video.poses
    return R[t], tr[t], piv


def build_model(video, cfg: HFMConfig) -> HFMModel:
    """Canonical Gaussians from the registration head mesh (one per vertex, THGS init)."""
    from geoface.mesh.io import load_mesh

    if video.mesh_path is None:
        raise SplatError("the registration folder has no head mesh (head.ply / head.obj)")
    m = load_mesh(video.mesh_path)
    C = getattr(m, "colors", None)
    if C is None:
        raise SplatError(f"{video.mesh_path}: the head mesh needs vertex colours")
    g = Gaussians.from_mesh(m.V, m.F, np.clip(np.asarray(C)[:, :3], 0, 1), opacity=cfg.init_opacity)
    y_t = cfg.y_split if cfg.y_split is not None else video.y_split
    return HFMModel(g, cfg, y_t)


def train_hfm(reg_dir, out_dir, cfg: HFMConfig | None = None, *, frames: slice | None = None,
              progress=None, log=print, callback=None) -> dict:
    """Register a person from an unoccluded video folder; saves ``out_dir`` (config.json,
    model.safetensors) and returns a summary (loss history, seconds, Gaussians, keys).
    ``callback(step, model, average)``, when given, runs after every step (``average``: the
    :class:`WeightAverage` once it has started, else None), e.g. to score the model as it trains."""
    from geoface.nn.losses import dssim
    from geoface.progress import progress as bar
    from geoface.splat.hfm_data import load_video
    from geoface.splat.rasterizer import rasterize

    cfg = cfg or HFMConfig()
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    video = load_video(reg_dir, need_mesh=True, frames=frames)
    model = build_model(video, cfg)
    cam = video.camera
    imgs, crops, boxes = _frames_tensors(video, cfg.crop)
    vgg = None
    if cfg.lambda_vgg > 0:
        if cfg.vgg_weights:
            vgg = VGGPerceptual(cfg.vgg_weights)
        elif log:
            log("hfm: no VGG weights given (--vgg-weights): training without the perceptual term")
    g = model.gaussians
    extent = float(model.scale) * 2
    opt = make_optimizer(g, {"means": cfg.lr_means * extent, "log_scales": 5e-3, "quats": 1e-3,
                             "opacity_logits": 2.5e-2, "colors": 2.5e-3}, eps=1e-15)
    nets = [p for n, p in model.named_parameters() if not n.startswith("gaussians.")]
    # Adam's usual ε for the networks: the 3DGS ε = 1e-15 turns the tiny, noisy gradients of
    # barely-used weights into full-size steps and kills ReLU units
    opt.add_param_group({"params": nets, "lr": cfg.lr_nets, "name": "nets", "eps": 1e-8})
    # static warm-up: the networks start from the identity deformation (zero last layers) and stay
    # frozen until the Gaussians fit the average face; trained from the first step, the encoder
    # tends to collapse θ to a constant while the residual is still dominated by the static fit
    # (seen on the synthetic head for one model seed in two), and the avatar never follows expressions
    n_warm = int(cfg.warmup * cfg.iters)
    for p in nets:
        p.requires_grad_(n_warm == 0)
    strategy = None
    if cfg.densify:
        every = min(100, max(10, cfg.iters // 10))
        dcfg = DensityConfig(refine_start=max(100, cfg.iters // 10) - 1, refine_stop=int(0.6 * cfg.iters),
                             refine_every=every, reset_every=0, max_gaussians=2 * len(g))
        strategy = SegregationStrategy(dcfg, extent, model.y_split, cfg.margin, model.upper_mask())
    history, order = [], []
    # the weights are averaged once the networks train and density control has stopped
    ema_start = max(n_warm, strategy.cfg.refine_stop if strategy is not None else 0) if cfg.ema > 0 else cfg.iters
    average = None
    t0 = time.perf_counter()
    bg = torch.zeros(3)
    steps = range(cfg.iters)
    if not callable(progress):
        steps = bar(steps, "registering (HFM-GS)", total=cfg.iters, quiet=None if progress is None else not progress)
    for it in steps:
        if it == n_warm and n_warm:
            for p in nets:
                p.requires_grad_(True)
        if not order:
            order = list(rng.permutation(len(imgs)))
        f = int(order.pop())
        if it % cfg.key_every == 0:
            model.refresh_keys()
        gt = imgs[f]
        gd = model(crops[f:f + 1], boxes[f:f + 1], _pose(video, f))
        rgb, alpha, depth, info = rasterize(gd, cam, background=bg, return_info=True)
        l1 = (rgb - gt).abs().mean()
        a, b = rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]
        ds = dssim(a, b)
        loss = (1 - cfg.lambda_rgb) * l1 + cfg.lambda_rgb * ds
        if vgg is not None:
            loss = loss + cfg.lambda_vgg * vgg(a, b)
        ls = boundary_loss(g.means[:, 1], strategy.upper if strategy is not None else model.upper_mask(),
                           model.y_split)
        loss = loss + cfg.lambda_split * ls
        if strategy is not None:
            strategy.step_pre_backward(info)
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
        rec = {"step": it, "loss": float(loss.detach()), "l1": float(l1.detach()), "n": len(g), "nets": it >= n_warm}
        if strategy is not None:
            counts = strategy.step_post_backward(g, opt, info, it)
            if counts["cloned"] or counts["split"] or counts["pruned"]:
                rec.update(cloned=counts["cloned"], split=counts["split"], pruned=counts["pruned"], n=len(g))
                model.refresh_keys()
        if it >= ema_start:
            if average is None:
                average = WeightAverage(model, cfg.ema)
            average.update(model)
        history.append(rec)
        if callable(progress) and (it % 50 == 0 or it == cfg.iters - 1):
            progress(it, rec)
        if callback is not None:
            callback(it, model, average)
    if average is not None:
        average.copy_to(model)
        model.refresh_keys()  # W_gm of the averaged weights
    model.refit_statistics(crops, boxes)  # the mapping's input statistics, for the final weights
    seconds = time.perf_counter() - t0
    save_hfm(model, out_dir)
    return {"seconds": seconds, "frames": len(imgs), "warmup_steps": n_warm,
            "averaged_steps": average.steps if average is not None else 0, "history": history, "n_gaussians": len(g), "n_upper": int(model.upper_mask().sum()),
            "dropped_children": strategy.dropped if strategy is not None else 0, "vgg": vgg is not None}


def write_model_dir(out_dir, module: nn.Module, meta: dict) -> Path:
    """``out_dir/model.safetensors`` (the module's state, written to a temporary name first) and
    ``out_dir/config.json`` (``meta``). Shared by the avatar models."""
    from safetensors.torch import save_file

    from geoface._io import atomic_path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().contiguous().cpu() for k, v in module.state_dict().items() if v is not None}
    with atomic_path(out / "model.safetensors") as tmp:
        save_file(sd, str(tmp))
    (out / "config.json").write_text(json.dumps(meta, indent=1))
    return out


def read_model_dir(model_dir, fmt: str, what: str) -> tuple[Path, dict, dict]:
    """(folder, config.json, state dict) of a model folder written by :func:`write_model_dir`
    whose config says ``"format": fmt``; any problem is a one-line SplatError."""
    d, meta = read_model_config(model_dir, fmt, what)
    return d, meta, _load_state(d / "model.safetensors")


def read_model_config(model_dir, fmt: str, what: str) -> tuple[Path, dict]:
    """(folder, config.json) of a model folder, validated (format, version, a ``config``
    object) before any weights are read; problems are :class:`ModelFolderError`."""
    from geoface.nn.config import check_version

    from .errors import ModelFolderError

    d = Path(model_dir)
    try:
        meta = json.loads((d / "config.json").read_text())
    except (OSError, ValueError) as e:
        raise ModelFolderError(f"{d}: not a {what} model folder (config.json: {type(e).__name__})") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        raise ModelFolderError(f"{d}/config.json: not a {what} model")
    check_version(meta, 1, where=f"{d}/config.json", error=ModelFolderError)
    if not isinstance(meta.get("config"), dict):
        raise ModelFolderError(f"{d}/config.json: 'config' must be a JSON object")
    return d, meta


def save_hfm(model: HFMModel, out_dir) -> None:
    write_model_dir(out_dir, model, {"format": "geoface-hfm-gs", "version": 1, "config": model.cfg.to_dict(),
                                     "y_split": model.y_split, "n_gaussians": len(model.gaussians)})


def load_hfm(model_dir) -> HFMModel:
    """Load a model folder; any problem is a one-line SplatError."""
    d, meta, sd = read_model_dir(model_dir, "geoface-hfm-gs", "HFM-GS")
    conf = dict(meta["config"])
    conf.setdefault("map_norm", False)  # folders written before the field read p_L raw
    conf.setdefault("detach_lower", False)  # and trained the lower networks through the mapping
    conf.setdefault("upsample", "params")  # before the field: W_dist spread the keys' deformations
    conf.setdefault("feat_norm", False)  # and MLP_mapping read f_U as W_gm gave it
    conf.setdefault("mapping_heads", 1)
    if not conf.get("gaussian_mapping", True):  # before the field: the unmapped upper face had its own MLP
        conf.setdefault("unmapped_upper", "separate" if any(k.startswith("mlp_up.") for k in sd) else "shared")
    cfg = HFMConfig.from_dict(conf, where=f"{d}/config.json")
    from .errors import ModelFolderError

    y_split = meta.get("y_split")
    if isinstance(y_split, bool) or not isinstance(y_split, (int, float)) or not math.isfinite(y_split):
        raise ModelFolderError(f"{d}/config.json: y_split must be a number; got {y_split!r}")
    n_meta = meta.get("n_gaussians")
    if n_meta is not None and (isinstance(n_meta, bool) or not isinstance(n_meta, int)):
        raise ModelFolderError(f"{d}/config.json: n_gaussians must be an integer; got {n_meta!r}")
    try:
        n = sd["gaussians.means"].shape[0]
        g = Gaussians(sd["gaussians.means"], sd["gaussians.log_scales"], sd["gaussians.quats"],
                      sd["gaussians.opacity_logits"], sd["gaussians.colors"], sd.get("gaussians.parent"))
        model = HFMModel(g, cfg, meta["y_split"], sd["center"], sd["scale"])
        model.load_state_dict(sd, strict=True)
    except (KeyError, RuntimeError, SplatError) as e:
        raise SplatError(f"{d}: model weights do not match config.json ({str(e).splitlines()[0][:160]})") from None
    if n != meta.get("n_gaussians", n):
        raise SplatError(f"{d}: {n} Gaussians in the weights, config.json says {meta['n_gaussians']}")
    model.eval()
    model.refresh_keys()
    return model


# ----------------------------------------------------------------------------- usage
def _frame_input(video, t: int, size: int, boxes: np.ndarray) -> tuple[Tensor, Tensor]:
    """Frame ``t``'s lower-face crop [1, 3, size, size] and crop box [1, 3] (``boxes`` =
    ``video.boxes()``), as the encoder takes them."""
    from geoface.splat.hfm_data import crop_lower_face

    crop = torch.tensor(crop_lower_face(video.frames[t], video.lower_landmarks(t), size))[None]
    return crop, torch.tensor(boxes[t:t + 1])


@torch.no_grad()
def remove_hmd(model: HFMModel, video, *, out_dir=None, camera=None, composite: bool = True):
    """Restore every frame of ``video`` (an :class:`HMDVideo`): render the avatar driven by the
    lower-face crop; where ``video.hmd_masks`` is known, paste the rendering into the occluded
    region only (``composite``). Streams frame by frame; returns (renders [T, H, W, 3] float32,
    per-frame seconds). Writes ``out_dir/frames/*.png`` when given (each file complete or absent)."""
    from geoface.splat.hfm_data import write_frame
    from geoface.splat.rasterizer import rasterize

    cam = camera or video.camera
    out = Path(out_dir) if out_dir is not None else None
    renders, times = [], []
    bg = torch.zeros(3)
    boxes = video.boxes()
    for t in range(len(video)):
        t0 = time.perf_counter()
        rgb = rasterize(model(*_frame_input(video, t, model.cfg.crop, boxes), _pose(video, t)), cam,
                        background=bg)[0].clamp(0, 1).numpy()
        times.append(time.perf_counter() - t0)
        renders.append(rgb)
        if out is not None:
            img = rgb
            if composite and video.hmd_masks is not None:
                img = np.where(video.hmd_masks[t][..., None], rgb, video.frames[t])
            write_frame(out, t, img)
    return np.stack(renders), np.asarray(times)


@torch.no_grad()
def expression_motion(model: HFMModel, video) -> dict:
    """How far the crop moves the Gaussians: per Gaussian, the RMS distance of its deformed
    centre (before the tracked head pose) from its mean over the frames of ``video``; averaged
    over the upper and the lower set, in millimetres (scene units are metres). Near zero means
    the avatar ignores the lower face (a collapsed encoder or dead deformation networks)."""
    boxes = video.boxes()
    P = torch.stack([model(*_frame_input(video, t, model.cfg.crop, boxes)).means for t in range(len(video))])
    rms = (P - P.mean(0)).pow(2).sum(-1).mean(0).sqrt() * 1000
    up = model.upper_mask()
    return {"upper_motion_mm": float(rms[up].mean()) if bool(up.any()) else 0.0,
            "lower_motion_mm": float(rms[~up].mean()) if bool((~up).any()) else 0.0}


EXPRESSION_TAU = 0.02     # a pixel belongs to the expression region where it changes by more than this
EXPRESSION_MIN_PIXELS = 10


def evaluate_hmd(model: HFMModel, video) -> dict:
    """PSNR/SSIM of the renders against ``video.gt`` on the whole face (foreground) and in the
    region the headset hides; FPS of the whole per-frame path (crop, encode, deform, render).

    Where the usage folder has ``gt_static_upper/`` (the synthetic videos: the same frames with
    brows and lids at rest), also the *expression region* of each frame: the occluded face pixels
    that the upper expression changes by more than ``EXPRESSION_TAU`` in some channel. On the
    synthetic head a render that is perfect except that it ignores the upper expression scores
    about 41 dB over the whole occluded region (most of it is forehead and lids at rest), so the
    occluded-region PSNR of a ~34 dB avatar mostly measures its static quality; ``psnr_expression``
    and ``ssim_expression`` score only what the upper expression changes (frames with at least
    ``EXPRESSION_MIN_PIXELS`` such pixels), and ``psnr_expression_rest`` is what the rest-pose
    frames themselves score there — an avatar must beat it to show it restored the expression."""
    if video.gt is None or video.hmd_masks is None:
        raise SplatError("evaluation needs gt/ and hmd_masks/ in the usage folder")
    R, times = remove_hmd(model, video)
    out = hmd_metrics(R, video)
    out.update(expression_motion(model, video))
    out.update(frames=len(video), fps=float(1.0 / np.median(times)), seconds_per_frame=float(np.median(times)))
    return out


def hmd_metrics(R: np.ndarray, video) -> dict:
    """The image metrics of :func:`evaluate_hmd` for renders ``R`` [T, H, W, 3] of ``video``."""
    from geoface.splat.fit import psnr, ssim_masked

    if video.gt is None or video.hmd_masks is None:
        raise SplatError("evaluation needs gt/ and hmd_masks/ in the usage folder")
    if R.shape != video.gt.shape:
        raise SplatError(f"renders {R.shape} do not match the usage frames {video.gt.shape}")
    face = video.gt.max(-1) > 0
    rest = video.gt_static_upper
    rows = {"psnr_face": [], "ssim_face": [], "psnr_occluded": [], "ssim_occluded": []}
    if rest is not None:
        rows.update(psnr_expression=[], ssim_expression=[], psnr_expression_rest=[], expression_pixels=[])
    for t in range(len(video)):
        m, o = face[t], video.hmd_masks[t] & face[t]
        rows["psnr_face"].append(psnr(R[t], video.gt[t], m))
        rows["psnr_occluded"].append(psnr(R[t], video.gt[t], o))
        rows["ssim_face"].append(ssim_masked(R[t], video.gt[t], m))
        rows["ssim_occluded"].append(ssim_masked(R[t], video.gt[t], o))
        if rest is not None:
            e = o & (np.abs(video.gt[t] - rest[t]).max(-1) > EXPRESSION_TAU)
            rows["expression_pixels"].append(float(e.sum()))
            if e.sum() >= EXPRESSION_MIN_PIXELS:
                rows["psnr_expression"].append(psnr(R[t], video.gt[t], e))
                rows["ssim_expression"].append(ssim_masked(R[t], video.gt[t], e))
                rows["psnr_expression_rest"].append(psnr(rest[t], video.gt[t], e))
    out = {k: float(np.nanmean(v)) if len(v) else float("nan") for k, v in rows.items()}
    if rest is not None:
        out["expression_frames"] = len(rows["psnr_expression"])
    return out
