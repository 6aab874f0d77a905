"""Weight averaging (Polyak / exponential moving average of a module's parameters)."""
from __future__ import annotations

import contextlib

import torch
from torch import nn

from geoface.nn.errors import NNError

__all__ = ["WeightAverage"]


class WeightAverage:
    """Exponential moving average of a module's parameters (Polyak averaging): ``update`` after
    each optimiser step folds the current values in with weight 1 − ``decay``; ``copy_to`` writes
    the bias-corrected averages into the module (the updates' values weighted by decay^age, over
    the updates made so far: a short run averages what it has). The parameters must keep their
    shapes while it runs (start it after density control has stopped adding and removing Gaussians)."""

    def __init__(self, module: nn.Module, decay: float):
        if not 0 <= decay < 1:
            raise NNError(f"weight average decay must be in [0, 1); got {decay}")
        self.decay = float(decay)
        self.avg = {n: torch.zeros_like(p.detach()) for n, p in module.named_parameters()}
        self.steps = 0

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        for n, p in module.named_parameters():
            a = self.avg[n]
            if a.shape != p.shape:
                raise NNError(f"weight average: {n} changed shape {tuple(a.shape)} -> {tuple(p.shape)}")
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
            raise NNError("weight average: no update yet")
        corr = 1 - self.decay ** self.steps
        for n, p in module.named_parameters():
            p.copy_(self.avg[n] / corr)
