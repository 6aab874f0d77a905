"""Networks of the ultra-high-resolution facial texture model (4K-texture paper).

Three UNet-like networks, all working in image space ([B, C, H, W], values in [0, 1]):

* :class:`NormalUVPredictor` — RGB → UV (2, in [0, 1]) + normal (3, unit length).
* :class:`GDE` (Global Distribution Extractor, run at 1024² in the paper) — image ⊕ UV ⊕
  normal → albedo 3 + micronormal 3 + specular 1, plus a per-UV offset of the output logits
  from hash features of the UV (``hash_mode="logit"``; the paper's concatenation of the hash
  features to the input is ``hash_mode="input"``).
* :class:`HFDR` (High-Frequency Detail Refiner, on full-resolution patches) — patch ⊕
  upsampled UV and normal crops → the same 7 maps, with the upsampled GDE guidance
  concatenated to its last hidden features before the output head.

Outputs are packed as :data:`MAPS` (albedo 0:3 in [0, 1], micronormal 3:6 as a unit vector
encoded to [0, 1] by n/2 + ½, specular 6:7 in [0, 1]).  Losses (paper): GDE = L1 + 1·Laplacian,
HFDR = L1 + 2·Laplacian (:func:`map_loss`).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as Fnn
from torch import Tensor, nn

from ..errors import LearnError
from geoface.nn.hashenc import HashEncoding
from geoface.nn.losses import laplacian_loss

HFDR_BANDS = ("full", "detail")
GDE_TONES = ("absolute", "relative")
HASH_MODES = ("input", "logit")
GAMMA = 2.2  # the photos' encoding (linear light = photo ** GAMMA)
MAPS = {"albedo": slice(0, 3), "micronormal": slice(3, 6), "specular": slice(6, 7)}
N_MAPS = 7


def _groups(c: int) -> int:
    for g in (8, 4, 2, 1):
        if c % g == 0:
            return g
    return 1


class ConvBlock(nn.Module):
    """(conv3×3 → GroupNorm → SiLU) × 2."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(cin, cout, 3, padding=1), nn.GroupNorm(_groups(cout), cout), nn.SiLU(),
            nn.Conv2d(cout, cout, 3, padding=1), nn.GroupNorm(_groups(cout), cout), nn.SiLU())

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


class UNet(nn.Module):
    """Plain UNet: ``widths`` channels per level, stride-2 conv down, bilinear up + skip.

    ``late_channels`` extra channels (e.g. guidance) are concatenated to the last hidden
    features, just before the 1×1 output head.  Input sides must be divisible by
    2^(len(widths) − 1).
    """

    def __init__(self, cin: int, cout: int, widths=(32, 64, 128), late_channels: int = 0):
        super().__init__()
        w = list(widths)
        if not w or min(w) < 1:
            raise LearnError(f"widths must be a non-empty list of positive ints; got {widths}")
        self.depth = len(w) - 1
        self.inc = ConvBlock(cin, w[0])
        self.down = nn.ModuleList(nn.Conv2d(w[i], w[i], 3, stride=2, padding=1) for i in range(self.depth))
        self.enc = nn.ModuleList(ConvBlock(w[i], w[i + 1]) for i in range(self.depth))
        self.dec = nn.ModuleList(ConvBlock(w[i + 1] + w[i], w[i]) for i in reversed(range(self.depth)))
        self.late = late_channels
        self.head = nn.Sequential(nn.Conv2d(w[0] + late_channels, w[0], 3, padding=1), nn.SiLU(),
                                  nn.Conv2d(w[0], cout, 1))

    def forward(self, x: Tensor, late: Tensor | None = None) -> Tensor:
        m = 2 ** self.depth
        if x.shape[-1] % m or x.shape[-2] % m:
            raise LearnError(f"input size {tuple(x.shape[-2:])} must be divisible by {m}")
        skips = [self.inc(x)]
        h = skips[0]
        for down, enc in zip(self.down, self.enc):
            h = enc(down(h))
            skips.append(h)
        for dec, skip in zip(self.dec, reversed(skips[:-1])):
            h = Fnn.interpolate(h, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            h = dec(torch.cat([h, skip], 1))
        if self.late:
            if late is None or late.shape[1] != self.late:
                raise LearnError(f"this network needs {self.late} guidance channels")
            h = torch.cat([h, late], 1)
        return self.head(h)


def pack_maps(raw: Tensor) -> Tensor:  # [B, 7, H, W] logits -> [B, 7, H, W] maps in [0, 1]
    albedo = torch.sigmoid(raw[:, 0:3])
    n = Fnn.normalize(raw[:, 3:6] + torch.tensor([0.0, 0.0, 1.0], device=raw.device,
                                                  dtype=raw.dtype)[None, :, None, None], dim=1)
    spec = torch.sigmoid(raw[:, 6:7])
    return torch.cat([albedo, n * 0.5 + 0.5, spec], 1)


def map_loss(pred: Tensor, target: Tensor, lap_weight: float = 1.0) -> tuple[Tensor, dict]:
    """L1 + ``lap_weight``·Laplacian over the 7 maps; parts per map for logging."""
    l1 = (pred - target).abs().mean()
    lap = laplacian_loss(pred, target)
    parts = {k: float((pred[:, s] - target[:, s]).abs().mean().detach()) for k, s in MAPS.items()}
    parts.update(l1=float(l1.detach()), laplacian=float(lap.detach()))
    return l1 + lap_weight * lap, parts


@dataclass
class TextureNetConfig:
    """Sizes of the three networks and the UV hash encoding (defaults: CPU-trainable)."""
    predictor_widths: list = field(default_factory=lambda: [16, 32, 64])
    gde_widths: list = field(default_factory=lambda: [32, 64, 128])
    hfdr_widths: list = field(default_factory=lambda: [16, 32, 64])
    hash_levels: int = 4
    hash_features: int = 2
    hash_log2_table: int = 16
    hash_base_res: int = 16
    hash_max_res: int = 128  # finest grid; 1024 overfitted 64 faces (docs/textures.md)
    use_hash: bool = True
    #: where the GDE's hash features go: "input" (concatenated to its input, as the paper) or
    #: "logit" (a linear map of them added to its output logits: a regional offset per UV
    #: position that the tone read from the photo does not pass through; chosen on the
    #: validation faces, docs/textures.md)
    hash_mode: str = "logit"
    #: what the HFDR may change: "full" (any frequency) or "detail" (only what the GDE's grid
    #: cannot hold: its residual minus the residual's own average over each GDE texel, so the
    #: refined maps keep the GDE's low band); see docs/textures.md
    hfdr_band: str = "full"
    #: how the GDE reads skin tone: "absolute" (albedo straight from the photo and the hash
    #: features) or "relative" (the photo divided by its tone — a learned weighted mean of its
    #: linear colour — and the albedo predicted as a factor of that tone, so the hash tables hold
    #: regional ratios, not the training faces' typical albedo); see docs/textures.md
    gde_tone: str = "absolute"

    def __post_init__(self):
        if self.hfdr_band not in HFDR_BANDS:
            raise LearnError(f"hfdr_band must be one of {', '.join(HFDR_BANDS)}; got {self.hfdr_band!r}")
        if self.hash_mode not in HASH_MODES:
            raise LearnError(f"hash_mode must be one of {', '.join(HASH_MODES)}; got {self.hash_mode!r}")
        if self.gde_tone not in GDE_TONES:
            raise LearnError(f"gde_tone must be one of {', '.join(GDE_TONES)}; got {self.gde_tone!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where: str = "config.json (nets)") -> "TextureNetConfig":
        from geoface.nn.config import config_from_dict

        # models saved before the options existed refine every band and read absolute tone
        return config_from_dict(cls, {"hfdr_band": "full", "gde_tone": "absolute", "hash_mode": "input", **d},
                                where=where, unknown="error")


class NormalUVPredictor(nn.Module):
    """RGB [B,3,H,W] → (uv [B,2,H,W] in [0,1], normal [B,3,H,W] unit)."""

    def __init__(self, widths=(16, 32, 64)):
        super().__init__()
        self.net = UNet(3, 5, widths)

    def forward(self, rgb: Tensor) -> tuple[Tensor, Tensor]:
        out = self.net(rgb)
        return torch.sigmoid(out[:, :2]), Fnn.normalize(out[:, 2:5], dim=1, eps=1e-6)


class GDE(nn.Module):
    """Image ⊕ UV ⊕ normal (⊕ hash(UV) with ``hash_mode="input"``) → 7 maps (coarse global
    distribution); with ``hash_mode="logit"`` a linear map of hash(UV) is added to the logits.

    With ``gde_tone="relative"`` the photo's tone μ (per channel, linear light) is a weighted
    mean of its pixels, the weights a softmax over pixels of a 1×1 convolution of features that
    a change of exposure or skin tone leaves alone (UV, normal, chromaticity).  The network sees
    the photo divided by μ and predicts the albedo's logit relative to logit(μ): a photo whose
    linear colour is c·(the same) has tone c·μ, the same network input, and an albedo of
    sigmoid(r + logit(c·μ)) — about c times the albedo wherever it is dark."""

    def __init__(self, cfg: TextureNetConfig):
        super().__init__()
        self.hash = (HashEncoding(2, cfg.hash_levels, cfg.hash_features, cfg.hash_log2_table,
                                  cfg.hash_base_res, cfg.hash_max_res, seed=0) if cfg.use_hash else None)
        self.hash_logit = None
        extra = self.hash.out_dim if self.hash is not None else 0
        if self.hash is not None and cfg.hash_mode == "logit":
            self.hash_logit = nn.Conv2d(extra, N_MAPS, 1)  # starts at zero: the photo-only GDE
            nn.init.zeros_(self.hash_logit.weight)
            nn.init.zeros_(self.hash_logit.bias)
            extra = 0
        self.net = UNet(3 + 2 + 3 + extra, N_MAPS, cfg.gde_widths)
        self.relative = cfg.gde_tone == "relative"
        if self.relative:
            self.tone_weight = nn.Conv2d(2 + 3 + 3, 1, 1)  # where to read the tone (see the class)

    def tone(self, rgb: Tensor, uv: Tensor, normal: Tensor) -> Tensor:
        """The photo's tone μ [B, 3, 1, 1] in linear light (relative mode)."""
        lin = rgb.clamp(0, 1) ** GAMMA
        chroma = lin / (lin.sum(1, keepdim=True) + 1e-6)  # 0 on the black background
        logits = self.tone_weight(torch.cat([uv, normal, chroma], 1)).flatten(1)
        w = torch.softmax(logits, 1).view(rgb.shape[0], 1, *rgb.shape[-2:])
        return (w * lin).sum((2, 3), keepdim=True).clamp(1e-3, 0.999)

    def forward(self, rgb: Tensor, uv: Tensor, normal: Tensor) -> Tensor:
        mu = self.tone(rgb, uv, normal) if self.relative else None
        x = [rgb if mu is None else rgb.clamp_min(0) / mu ** (1 / GAMMA), uv, normal]
        h = self.hash(uv.permute(0, 2, 3, 1)).permute(0, 3, 1, 2) if self.hash is not None else None
        if h is not None and self.hash_logit is None:
            x.append(h)
        raw = self.net(torch.cat(x, 1))
        if self.hash_logit is not None:
            raw = raw + self.hash_logit(h)
        if mu is not None:
            raw = torch.cat([raw[:, :3] + torch.logit(mu), raw[:, 3:]], 1)
        return pack_maps(raw)


class HFDR(nn.Module):
    """Full-resolution patch ⊕ UV, normal crops → 7 maps; GDE guidance joins the last features."""

    def __init__(self, cfg: TextureNetConfig):
        super().__init__()
        self.net = UNet(3 + 2 + 3, N_MAPS, cfg.hfdr_widths, late_channels=N_MAPS)
        # the refiner starts as the identity on the guidance (a zero residual): a random start
        # adds noise that training can settle into keeping instead of learning detail
        nn.init.zeros_(self.net.head[-1].weight)
        nn.init.zeros_(self.net.head[-1].bias)
        self.band = cfg.hfdr_band

    def forward(self, patch: Tensor, uv: Tensor, normal: Tensor, guidance: Tensor,
                grid: tuple[int, int] | None = None) -> Tensor:
        """``grid``: how many GDE texels the patch spans (rows, cols); needed when
        ``hfdr_band`` is "detail" (the patch must be aligned to the GDE's texels)."""
        raw = self.net(torch.cat([patch, uv, normal], 1), late=guidance)
        # residual on the guidance: refine, not re-predict, the coarse maps
        res = torch.tanh(raw) * 0.5
        if self.band == "detail":
            if grid is None:
                raise LearnError("the HFDR refines detail only: pass grid, the patch's size in GDE texels")
            low = Fnn.interpolate(res, size=tuple(grid), mode="area")  # the residual's mean per texel
            res = res - Fnn.interpolate(low, size=res.shape[-2:], mode="nearest")
        out = (guidance + res).clamp(0, 1)
        n = Fnn.normalize(out[:, 3:6] * 2 - 1, dim=1, eps=1e-6)  # keep micronormals unit length
        return torch.cat([out[:, 0:3], n * 0.5 + 0.5, out[:, 6:7]], 1)
