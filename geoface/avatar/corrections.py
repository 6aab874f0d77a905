"""Per-frame corrections of tracked head poses, learned with an avatar's image loss (THGS's joint
optimisation; HFM-GS's registration poses when they come from landmarks)."""
from __future__ import annotations

import torch
from torch import Tensor

from geoface.avatar.kinematics import axis_angle_to_matrix

__all__ = ["FrameCorrections", "corrected_pose"]


class FrameCorrections:
    """Steps for per-frame corrections (pose, expression), one frame at a time.

    A frame's row of ``d_rot``/``d_transl``/``d_expr`` gets a gradient only when that frame is
    drawn, once every few hundred steps. Adam keeps moving every row on its stale momentum, and
    normalises each step to about the learning rate whatever the gradient: the corrections then
    wander (5.5° on an ICT capture whose poses were exact). Here only the drawn row moves, by
    its gradient over a root-mean-square shared by all frames (RMSprop, per joint and axis):
    steps grow with the misfit and vanish where the frame fits."""

    def __init__(self, params_lrs, beta: float = 0.99, eps: float = 1e-12):
        # per tensor: its rate, which of a row's entries may move (a bool mask broadcast over the
        # row; all when not given), the running mean square of its gradients, and how many it has
        # had (expression corrections start a stage later than pose ones: each debiases by its own count)
        self.items = []
        for p, lr, *mask in params_lrs:
            m = torch.as_tensor(mask[0], dtype=p.dtype, device=p.device) if mask else torch.ones((), device=p.device)
            self.items.append([p, float(lr), m, torch.zeros(p.shape[1:], device=p.device), 0])
        self.beta, self.eps = beta, eps

    @torch.no_grad()
    def step(self, row: int, scale: float = 1.0) -> None:
        """Move row ``row`` of each tensor that has a gradient; ``scale`` multiplies the rates
        (a schedule that lets the corrections settle)."""
        for item in self.items:
            p, lr, m, v, n = item
            if p.grad is None:
                continue
            item[4] = n = n + 1
            g = p.grad[row] * m
            v.mul_(self.beta).add_((1 - self.beta) * g * g)
            p[row] -= scale * lr * g / ((v / (1 - self.beta ** n)).sqrt() + self.eps)

    def zero_grad(self) -> None:
        for p, *_ in self.items:
            p.grad = None


def corrected_pose(R: Tensor, t: Tensor, pivot: Tensor, d_rot: Tensor, d_t: Tensor, center: Tensor):
    """The pose (R', t', pivot) of a tracked pose X' = R (X − pivot) + pivot + t corrected on the
    head: X' = R (R_d (X − c) + c + d_t − pivot) + pivot + t, R_d the rotation of the rotation
    vector ``d_rot`` about the head's centre ``c`` = ``center``, ``d_t`` a translation in the
    head's frame.  Differentiable in ``d_rot`` and ``d_t``."""
    Rd = axis_angle_to_matrix(d_rot[None])[0]
    Rn = R @ Rd
    # R (Rd (X − c) + c + d_t − p) + p + t = Rn (X − p) + p + [Rn p − R Rd c + R (c + d_t − p) + t]
    tn = Rn @ pivot - Rn @ center + R @ (center + d_t - pivot) + t
    return Rn, tn, pivot
