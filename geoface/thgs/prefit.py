"""Fitting THGS's audio articulation to the mouth landmarks of all training frames at once (ours).

In training, :class:`~geoface.thgs.model.AudioArticulation` (audio → jaw and mouth blendshapes)
learns from one frame per step, through the rendered image and the landmark term; after a
3000-step run it opens the training frames' lips less than their landmarks do.
:func:`prefit_articulation` fits it before that, when it switches on, to the landmarks alone:
full-batch Adam on the robust reprojection error (the training's own landmark term) of the
landmarks' Gaussians, posed by each frame's tracking plus the network's output, over all training
frames together. The number of steps is chosen on the last ``val_fraction`` of the training
frames (a contiguous block, so neighbouring frames do not leak), then the fit is redone on all of
them for that many steps. Off by default (``THGSConfig.artic_prefit``, ``geoface talk train
--prefit``): on the validation person of docs/thgs.md it gained in the mouth but not over the whole
image.
"""
from __future__ import annotations

import copy

import numpy as np
import torch
from torch import Tensor

from geoface.avatar.kinematics import joint_transforms, skin_points

__all__ = ["prefit_articulation", "prefit_training", "posed_points"]


def posed_points(model, idx, rot: Tensor, transl: Tensor, expr: Tensor) -> Tensor:
    """World positions [T, M, 3] of the Gaussians ``idx`` [M] for a batch of frames (rot [T, J, 3],
    transl [T, 3], expr [T, K]): the template's blendshapes (with LEB's learned part), then linear
    blend skinning — the model's own deformation without SAAM."""
    g = model.gaussians
    Xc = g.means[idx].detach()
    B = model.leb.basis().detach()[:, g.parent[idx]]  # [K, M, 3]
    X = Xc + torch.einsum("tk,kmc->tmc", expr, B)
    with torch.no_grad():
        W = model.skin(Xc)  # [M, J]
    return skin_points(X, W, joint_transforms(model.joints, model.parents, rot, transl))  # A: [T, J, 4, 4]


def prefit_articulation(model, audio: Tensor, rot, transl, expr, idx, points, camera, *, max_steps: int = 2000,
                        lr: float = 1e-3, val_fraction: float = 0.15, patience: int = 100) -> dict:
    """Fit ``model.artic`` in place to the landmarks ``points`` [T, M, 2] (pixels) of the Gaussians
    ``idx`` [M] over T training frames (normalised audio [T, D]; tracking rot/transl/expr, with
    the frames' current pose corrections folded in). Returns {"steps", "val_px", "px_before",
    "px_after"}: the chosen step count, the held-back block's mean landmark error then, and the
    mean error over all T frames before and after (pixels)."""
    from geoface.thgs.data import landmark_loss

    dev = model.V0.device
    f32 = dict(dtype=torch.float32, device=dev)
    rot, transl, expr, P = (torch.as_tensor(a, **f32) for a in (rot, transl, expr, points))
    audio = audio.to(**f32)
    T = len(rot)
    uj = (~model.tracked_joints)[:, None].to(**f32)
    ue = (~model.tracked_expr).to(**f32)
    idx = torch.as_tensor(np.asarray(idx), dtype=torch.long, device=dev)

    def err(frames, robust=True):
        dr, de = model.artic(audio[frames])
        Xp = posed_points(model, idx, rot[frames] + dr * uj, transl[frames], expr[frames] + de * ue)
        if robust:
            return landmark_loss(Xp.reshape(-1, 3), camera, P[frames].reshape(-1, 2)) * camera.width
        uv = camera.project(Xp.reshape(-1, 3))[0]
        return (uv - P[frames].reshape(-1, 2)).norm(dim=-1).mean()

    def run(frames, steps, val=None):  # -> (the held-back block's best error, its step)
        opt = torch.optim.Adam(model.artic.parameters(), lr=lr)
        best, best_step = float("inf"), 0
        for s in range(1, steps + 1):
            opt.zero_grad()
            err(frames).backward()
            opt.step()
            if val is not None:
                with torch.no_grad():
                    v = float(err(val, robust=False))
                if v < best:
                    best, best_step = v, s
                elif s - best_step >= patience:
                    break
        return best, best_step

    allf = torch.arange(T, device=dev)
    with torch.no_grad():
        before = float(err(allf, robust=False))
    start = copy.deepcopy(model.artic.state_dict())
    n_val = int(round(T * val_fraction))
    if n_val >= 2 and T - n_val >= 2:
        val_px, steps = run(allf[: T - n_val], max_steps, allf[T - n_val:])
        model.artic.load_state_dict(start)
    else:
        val_px, steps = float("nan"), max_steps
    run(allf, steps)
    with torch.no_grad():
        after = float(err(allf, robust=False))
    return {"steps": int(steps), "val_px": val_px, "px_before": before, "px_after": after}


def prefit_training(model, data, tr, audio: Tensor, lmk) -> dict:
    """:func:`prefit_articulation` on the training frames ``tr`` of a talking capture (audio
    features [T, D'] as the model reads them, not yet normalised; ``lmk`` = (the Gaussian of each
    mouth landmark, pixels [T, M, 2]); the frames' pose corrections so far folded in); {} without
    landmarks or an audio articulation."""
    if lmk is None or model.artic is None:
        return {}
    dev = model.V0.device
    with torch.no_grad():
        rot, transl, expr = (torch.as_tensor(a[tr], dtype=torch.float32, device=dev) + d[tr]
                             for a, d in ((data.rot, model.d_rot), (data.transl, model.d_transl), (data.expr, model.d_expr)))
    return prefit_articulation(model, model.normalize_audio(audio[tr]), rot, transl, expr, lmk[0], lmk[1][tr], data.camera)
