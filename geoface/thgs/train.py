"""Training a THGS avatar on a talking capture (:func:`train_thgs`): the staged schedule
(skinning and pose, expression, blendshapes, SAAM) and the held-out split."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from geoface.errors import AvatarError
from geoface.avatar.corrections import FrameCorrections
from geoface.thgs.model import THGSConfig, THGSModel
from geoface.thgs.inference import save_thgs


def train_heldout_split(n: int, heldout: float):
    k = max(1, int(round(n * (1 - heldout)))) if heldout > 0 else n
    return np.arange(k), np.arange(k, n)


def train_thgs(data_dir, out_dir, cfg: THGSConfig | None = None, *, progress=None, log=print,
               device: str = "cpu") -> dict:
    """Fit a THGS avatar to a talking data folder (first 1 − heldout of the frames).  ``device``:
    "cpu" or "cuda" (the gsplat rasteriser when installed, else the torch one on the GPU); the
    saved model is the same either way."""
    from geoface.nn.config import resolve_device
    from geoface.nn.losses import dssim
    from geoface.progress import progress as bar
    from geoface.splat.density import make_optimizer
    from geoface.splat.rasterizer import rasterize
    from geoface.thgs.data import landmark_loss, load_talking, mouth_landmark_targets
    from geoface.thgs.prefit import prefit_training

    cfg = cfg or THGSConfig()
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    data = load_talking(data_dir)
    tr, _ = train_heldout_split(len(data), cfg.heldout)
    model = THGSModel(data.template, cfg, data.audio.shape[1], len(data))
    A = model.audio_input(data.audio)
    model.audio_ref.copy_(torch.quantile(A[tr], 0.02, dim=0))
    model.audio_scale.copy_(A[tr].std(0).clamp_min(1e-3))
    model.tracked_joints.copy_(torch.as_tensor(data.tracked_joints))
    model.tracked_expr.copy_(torch.as_tensor(data.tracked_expr))
    dev = resolve_device(device, AvatarError) or "cpu"
    model.to(dev)
    A = A.to(dev)
    g = model.gaussians
    ext = float(np.ptp(data.template.V, 0).max())
    opt = make_optimizer(g, {"means": cfg.lr_means * ext, "log_scales": 5e-3, "quats": 1e-3,
                             "opacity_logits": 2.5e-2, "colors": 1e-2}, eps=1e-15)
    opt.add_param_group({"params": [model.skin.offsets], "lr": cfg.lr_nets * 0.1, "name": "skin"})
    # what the tracker did not measure (a jaw, lips left to the audio) gets no per-frame correction:
    # one would fit each training frame's mouth and leave the audio module nothing to learn;
    # translation corrections in metres: the rotation's step times the head's size
    frame_opt = FrameCorrections([(model.d_rot, cfg.lr_pose, torch.tensor(data.tracked_joints)[:, None]),
                                  (model.d_transl, cfg.lr_pose * ext),
                                  (model.d_expr, cfg.lr_pose, torch.tensor(data.tracked_expr))])
    opt.add_param_group({"params": [model.leb.delta], "lr": cfg.lr_nets * 0.01, "name": "leb"})
    if model.saam is not None:
        opt.add_param_group({"params": list(model.saam.parameters()), "lr": cfg.lr_nets, "name": "saam"})
    if model.artic is not None:
        opt.add_param_group({"params": list(model.artic.parameters()), "lr": cfg.lr_nets, "name": "artic"})
    imgs = torch.tensor(data.frames, device=dev)
    lmk = mouth_landmark_targets(data) if cfg.lambda_landmarks > 0 else None
    if lmk is not None:  # the Gaussian bound to each landmark's vertex
        lmk = ([int(i[0]) for i in model.gaussians_of(lmk[0])], lmk[1])
    stages = cfg.stages()
    history, order = [], []
    bg = torch.zeros(3, device=dev)
    t0 = time.perf_counter()
    steps = range(cfg.iters)
    if not callable(progress):
        steps = bar(steps, "training THGS", total=cfg.iters, quiet=None if progress is None else not progress)
    prefit = None
    for it in steps:
        model.stage = sum(it >= s for s in stages)
        if model.stage >= 2 and prefit is None:
            prefit = prefit_training(model, data, tr, A, lmk) if cfg.artic_prefit else {}
        if not order:
            order = list(rng.permutation(tr))
        f = int(order.pop())
        gd = model(data.rot[f], data.transl[f], data.expr[f], A[f], frame=f)
        rgb = rasterize(gd, data.camera, background=bg)[0]
        gt = imgs[f]
        l1 = (rgb - gt).abs().mean()
        loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * dssim(rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])
        loss = loss + cfg.lambda_vertex * model.vertex_loss() / ext**2
        lm = (cfg.lambda_landmarks * landmark_loss(gd.means[lmk[0]], data.camera, lmk[1][f])
              if lmk is not None and model.stage >= 2 else None)
        if lm is not None and cfg.landmarks_pose:
            loss, lm = loss + lm, None
        if model.stage >= 3:
            if cfg.use_leb:
                loss = loss + cfg.lambda_leb * model.leb.penalty() / ext**2
            loss = loss + cfg.lambda_normal * model.normal_loss()
        if lm is not None:  # the landmark term's gradient reaches the networks, not the pose corrections
            lm.backward(retain_graph=True)
            frame_opt.zero_grad()
        loss.backward()
        loss = loss if lm is None else loss + lm.detach()
        for grp in opt.param_groups:  # staged schedule: parts not yet switched on keep still
            name = grp["name"]
            on = {"skin": model.stage >= 1, "leb": model.stage >= 3 and cfg.use_leb,
                  "saam": model.stage >= 4, "artic": model.stage >= 2}.get(name, True)
            if not on:
                for p in grp["params"]:
                    p.grad = None
        opt.step()
        opt.zero_grad(set_to_none=True)
        if model.stage >= 1:  # pose corrections from the first stage (expression ones act from the second)
            frame_opt.step(f, cfg.pose_decay ** -((it - stages[0]) / max(cfg.iters - 1 - stages[0], 1)))
        frame_opt.zero_grad()
        history.append({"step": it, "loss": float(loss.detach()), "l1": float(l1.detach()), "stage": model.stage})
        if callable(progress) and (it % 50 == 0 or it == cfg.iters - 1):
            progress(it, history[-1])
    save_thgs(model.cpu(), out_dir)
    from geoface.avatar.capture import camera_to_json
    (Path(out_dir) / "camera.json").write_text(json.dumps(camera_to_json(data.camera)))
    return {"seconds": time.perf_counter() - t0, "history": history, "stages": stages, "n_gaussians": len(g),
            "artic_prefit": prefit or {}}
