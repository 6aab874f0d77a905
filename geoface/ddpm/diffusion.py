"""The denoiser of :mod:`geoface.ddpm.model` and what drives it: the UNet (optionally over pixel
blocks), the noise schedule (optionally shifted), the prediction target and loss, the EMA of the
weights and the learning-rate schedule.  Configured by :class:`geoface.ddpm.model.DDPMConfig`."""
from __future__ import annotations

import torch

from ..errors import CheckpointError

__all__ = ["build_unet", "PatchedUNet", "build_scheduler", "shifted_cosine_betas", "ddpm_target", "ddpm_loss", "EMA",
           "learning_rate"]


def build_unet(cfg: "DDPMConfig"):
    from diffusers import UNet2DConditionModel
    n = len(cfg.block_out_channels)
    levels = range(n - 1) if cfg.attention_levels is None else cfg.attention_levels
    bad = [k for k in levels if not 0 <= int(k) < n]
    if bad:
        raise CheckpointError(f"attention_levels must lie in 0..{n - 1}; got {tuple(levels)}")
    attn = [k in set(int(k) for k in levels) for k in range(n)]
    p = int(cfg.patch)
    unet = UNet2DConditionModel(
        sample_size=cfg.res // p, in_channels=cfg.channels * p * p, out_channels=cfg.channels * p * p,
        down_block_types=tuple("CrossAttnDownBlock2D" if a else "DownBlock2D" for a in attn),
        mid_block_type="UNetMidBlock2DCrossAttn",
        up_block_types=tuple("CrossAttnUpBlock2D" if a else "UpBlock2D" for a in reversed(attn)),
        block_out_channels=tuple(cfg.block_out_channels), layers_per_block=cfg.layers_per_block,
        cross_attention_dim=cfg.cross_attention_dim, attention_head_dim=cfg.attention_head_dim,
        norm_num_groups=cfg.norm_num_groups)
    return PatchedUNet(unet, p) if p > 1 else unet


class PatchedUNet(torch.nn.Module):
    """A UNet over ``patch x patch`` pixel blocks: ``x [B, C, R, R]`` is unshuffled to
    ``[B, C p², R/p, R/p]``, denoised, and shuffled back.  Same call and output as the UNet."""

    def __init__(self, unet: torch.nn.Module, patch: int):
        super().__init__()
        self.unet, self.patch = unet, int(patch)

    def forward(self, x, t, encoder_hidden_states=None):
        from types import SimpleNamespace
        f = torch.nn.functional
        y = self.unet(f.pixel_unshuffle(x, self.patch), t, encoder_hidden_states=encoder_hidden_states).sample
        return SimpleNamespace(sample=f.pixel_shuffle(y, self.patch))

    def enable_gradient_checkpointing(self):
        self.unet.enable_gradient_checkpointing()


def build_scheduler(cfg: "DDPMConfig", kind: str = "ddpm", clip: float | None = None):
    """``clip``: clamp the predicted x0 to [-clip, clip] at each sampling step (None = off).

    With squaredcos_cap_v2 and epsilon prediction, alpha_bar near t = T is ~1e-5, so an unclipped
    x0 estimate amplifies small epsilon errors ~300x: samples of a briefly trained model came out as
    per-pixel noise with |x| up to ~40.  The training data lie in [-1, 1], so clip=1 is the bound.
    """
    from diffusers import DDIMScheduler, DDPMScheduler
    on = clip is not None and clip > 0
    kw = {}
    if float(cfg.schedule_shift) != 1.0:
        kw["trained_betas"] = shifted_cosine_betas(cfg.num_train_timesteps, float(cfg.schedule_shift))
    s = DDPMScheduler(num_train_timesteps=cfg.num_train_timesteps, beta_schedule="squaredcos_cap_v2",
                      prediction_type=cfg.prediction, clip_sample=on,
                      clip_sample_range=float(clip) if on else 1.0, **kw)
    if kind == "ddpm":
        return s
    if kind == "ddim":
        return DDIMScheduler.from_config(s.config)
    raise CheckpointError(f"scheduler must be 'ddpm' or 'ddim'; got {kind!r}")


def shifted_cosine_betas(T: int, shift: float) -> list[float]:
    """The betas of the cosine schedule (``squaredcos_cap_v2``) with its log-SNR lowered by
    ``2 log(shift)``: ``alpha_bar' = sigmoid(logit(alpha_bar) - 2 log shift)``."""
    import math

    def abar(u: float) -> float:
        a = math.cos((u + 0.008) / 1.008 * math.pi / 2) ** 2
        if a <= 0.0:
            return 0.0
        if a >= 1.0:
            return 1.0
        return 1.0 / (1.0 + (1.0 - a) / a * shift * shift)
    out = []
    for i in range(T):
        a0, a1 = abar(i / T), abar((i + 1) / T)
        out.append(min(1.0 - a1 / a0, 0.999) if a0 > 0 else 0.999)
    return out


def ddpm_target(sched, x0: torch.Tensor, eps: torch.Tensor, t: torch.Tensor, prediction: str) -> torch.Tensor:
    """What the UNet is trained to output for ``x_t = q(x0, eps, t)``."""
    if prediction == "epsilon":
        return eps
    if prediction == "sample":
        return x0
    return sched.get_velocity(x0, eps, t)


def ddpm_loss(eps_pred: torch.Tensor,  # [B, C, N, N]
              eps: torch.Tensor,       # [B, C, N, N]
              modalities=("position", "normal", "texture"),
              ) -> tuple[torch.Tensor, dict]:
    """Eq. (12): sum over modalities (3 channels each, in ``modalities`` order) of the L1 error on the prediction target (epsilon in the paper)."""
    parts = {m: (eps_pred[:, 3 * k:3 * k + 3] - eps[:, 3 * k:3 * k + 3]).abs().mean() for k, m in enumerate(modalities)}
    return sum(parts.values()), {m: float(v.detach()) for m, v in parts.items()}


class EMA:
    """Exponential moving average of a module's parameters (shadow copy, float32)."""

    def __init__(self, model: torch.nn.Module, decay: float):
        self.decay = float(decay)
        self.shadow = {k: v.detach().clone().float() for k, v in model.state_dict().items()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        d = min(self.decay, (1 + step) / (10 + step))  # warm-up as in diffusers' EMAModel
        shadow, live = [], []
        for k, v in model.state_dict().items():
            if self.shadow[k].device != v.device:  # the model moved (accelerate, resume on a GPU)
                self.shadow[k] = self.shadow[k].to(v.device)
            if v.dtype.is_floating_point:
                shadow.append(self.shadow[k])
                live.append(v.detach().float())
            else:
                self.shadow[k].copy_(v)
        if shadow:  # shadow = d shadow + (1 - d) live, in a few multi-tensor kernels
            torch._foreach_lerp_(shadow, live, 1 - d)


def learning_rate(cfg: "DDPMConfig", step: int) -> float:
    """The learning rate of step ``step`` (0-based) under ``cfg.lr_schedule``."""
    if cfg.lr_schedule == "constant":
        return float(cfg.lr)
    import math
    u = min(max(step / max(int(cfg.steps) - 1, 1), 0.0), 1.0)
    return float(cfg.lr) * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * u)))
