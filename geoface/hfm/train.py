"""Registering a person with HFM-GS: the VGG perceptual loss, training on an unoccluded video and
calibrating the usage poses (the model folder: :mod:`geoface.hfm.io`)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from geoface.splat.density import DensityConfig, make_optimizer
from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians
from geoface.nn.average import WeightAverage
from geoface.hfm.blocks import SegregationStrategy, boundary_loss
from geoface.hfm.model import HFMConfig, HFMModel
from geoface.avatar.model_dir import load_model_state
from geoface.hfm.io import REGISTRATION_POSES, save_hfm, save_registration_poses


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
        sd = load_model_state(weights)
        sd = {k[len("features."):] if k.startswith("features.") else k: v for k, v in sd.items()}
        own = self.features.state_dict()
        missing = [k for k in own if k not in sd]
        if missing:
            raise AvatarError(f"{weights}: not VGG-16 feature weights (missing {missing[:3]})")
        try:
            self.features.load_state_dict({k: sd[k] for k in own})
        except RuntimeError as e:
            raise AvatarError(f"{weights}: VGG-16 weights of the wrong shape ({str(e).splitlines()[0]})") from None
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


# ----------------------------------------------------------------------------- training
def _frames_tensors(video, crop):
    imgs = torch.tensor(video.frames, dtype=torch.float32)
    crops = torch.tensor(video.crops(crop), dtype=torch.float32)
    return imgs, crops, torch.tensor(video.boxes())


def frame_pose(video, t):
    """Frame ``t``'s tracked head pose (R, t, pivot) or None."""
    if video.poses is None:
        return None
    R, tr, piv = video.poses
    return R[t], tr[t], piv


def _head_mesh(video):
    from geoface.mesh.io import load_mesh

    if video.mesh_path is None:
        raise AvatarError("the registration folder has no head mesh (head.ply / head.obj)")
    return load_mesh(video.mesh_path)


def registration_poses(video, poses: str = "auto", log=None, mesh=None, fit: str = "rigid") -> dict:
    """Set ``video.poses`` for registration and say where they came from: ``"file"`` (the folder's
    ``head_poses.npz``), ``"landmarks"`` (fitted to the landmarks, :mod:`geoface.avatar.head_pose`)
    or ``"auto"`` (the file when there is one).  Returns a summary (source, fit error) with the
    landmarks placed on the canonical head (``landmarks3d``).  ``mesh``: the loaded head mesh
    (default: the folder's).  ``fit``: the landmarks the poses are fitted to, ``"rigid"`` (all
    that move little with expressions), ``"stable"`` (those of them that stay put best,
    :data:`~geoface.avatar.head_pose.STABLE_NAMES`; iBUG 68 videos, else as "rigid") or ``"lower"``
    (those a headset leaves visible, :data:`~geoface.avatar.head_pose.LOWER_RIGID_NAMES`, as the usage
    video's poses are fitted)."""
    if poses not in ("auto", "file", "landmarks"):
        raise AvatarError(f"poses must be 'auto', 'file' or 'landmarks'; got {poses!r}")
    if poses == "file" and video.poses is None:
        raise AvatarError("--poses file: the registration folder has no head_poses.npz")
    from geoface.avatar.head_pose import LOWER_RIGID_NAMES, STABLE_NAMES, canonical_landmarks, poses_from_landmarks

    m = mesh if mesh is not None else _head_mesh(video)
    if video.poses is not None and poses != "landmarks":
        R, t, p = video.poses
        names, P = canonical_landmarks(video, m.V, m.F, (R[0], t[0], p))
        return {"poses": "file", "landmarks3d": {"names": names, "points": P.round(7).tolist()}}
    if fit not in ("rigid", "stable", "lower"):
        raise AvatarError(f"registration landmarks must be 'rigid', 'stable' or 'lower'; got {fit!r}")
    stable = None
    if fit == "stable" and set(STABLE_NAMES) <= set(video.names):  # else (not the iBUG 68) as "rigid"
        stable = [video.names.index(n) for n in STABLE_NAMES]
    res = poses_from_landmarks(video, m.V, m.F, indices=stable, fit_names=LOWER_RIGID_NAMES if fit == "lower" else None)
    names, P = res["all_names"], res["all_points3d"]
    video.poses = (res["R"], res["t"], res["pivot"])
    info = {"poses": "landmarks", "pose_landmarks": len(res["names"]),
            "pose_fit_rms_px": round(float(np.nanmedian(res["rms_px"])), 3),
            "pose_fit_worst_px": round(float(np.nanmax(res["rms_px"])), 3),
            "landmarks3d": {"names": names, "points": P.round(7).tolist()}}
    if log:
        log(f"hfm: head poses from {info['pose_landmarks']} landmarks per frame (median fit {info['pose_fit_rms_px']} px)")
    return info


def head_pose_loss(model: HFMModel, theta: Tensor, target: Tensor) -> Tensor:
    """Squared error of the head pose MLP_head_pose reads from the latent ``theta`` [1, L] against
    ``target`` [6]; with ``cfg.image_pose_detach`` it trains the pose MLP alone (θ detached), else
    the encoder too."""
    return ((model.head_pose_params(theta.detach() if model.cfg.image_pose_detach else theta)[0] - target) ** 2).sum()


def calibrate_usage_poses(model: HFMModel, video, source: str = "landmarks") -> dict | None:
    """Learn ``model.pose_calibration`` from the registration ``video`` (its ``poses`` set, as
    :func:`registration_poses` leaves them; ``source``: where they came from, "file" or
    "landmarks"): how head poses fitted to the landmarks below a headset
    miss the registration poses, as a function of the lower face's landmarks
    (:func:`~geoface.avatar.head_pose.calibrate_lower_poses`, ``pose_calibration`` components;
    ``pose_calibration_weighted``: those poses weigh each landmark by how little it moved).
    None (nothing learned) without iBUG-68 landmarks, with ``pose_calibration=0``, or when the
    registration poses were fitted to the lower landmarks themselves."""
    from geoface.avatar.capture import IBUG68_LOWER, IBUG68_NAMES
    from geoface.avatar.head_pose import calibrate_lower_poses, landmark_expressions

    cfg, lm = model.cfg, model.landmarks3d
    model.pose_calibration = None
    lowered = source == "landmarks" and cfg.registration_landmarks == "lower"
    if not cfg.pose_calibration or lm is None or lowered or tuple(video.names) != tuple(IBUG68_NAMES):
        return None
    draws = cfg.pose_calibration_expressions
    model.pose_calibration = calibrate_lower_poses(
        video.camera, lm["names"], lm["points"], video.landmarks, video.names, video.poses, fit_names=cfg.usage_fit_names,
        feature_names=[IBUG68_NAMES[i] for i in IBUG68_LOWER], components=cfg.pose_calibration,
        ridge=cfg.pose_calibration_ridge, weighted=cfg.pose_calibration_weighted,
        expressions=landmark_expressions(lm["names"], lm["points"]) if draws else None, draws=draws, seed=cfg.seed)
    return model.pose_calibration


def _ict_identity(reg_dir) -> list | None:
    """The registration capture's ICT identity weights (``meta.json``'s ``ict_identity``, which
    `geoface capture` writes: its head mesh and poses are that head's), or None."""
    from geoface.capture import Capture
    from geoface.hfm.io import identity_weights

    ident = Capture(reg_dir).meta().get("ict_identity")
    try:
        return None if ident is None else identity_weights(ident)
    except ValueError:
        return None


def build_model(video, cfg: HFMConfig, mesh=None) -> HFMModel:
    """Canonical Gaussians from the registration head mesh (one per vertex, THGS init);
    ``mesh``: that mesh loaded (default: read from the folder)."""
    m = mesh if mesh is not None else _head_mesh(video)
    C = getattr(m, "colors", None)
    if C is None:
        raise AvatarError(f"{video.mesh_path}: the head mesh needs vertex colours")
    g = Gaussians.from_mesh(m.V, m.F, np.clip(np.asarray(C)[:, :3], 0, 1), opacity=cfg.init_opacity)
    y_t = cfg.y_split if cfg.y_split is not None else video.y_split
    lo, hi = float(m.V[:, 1].min()), float(m.V[:, 1].max())
    if not (isinstance(y_t, (int, float)) and lo < float(y_t) < hi):
        raise AvatarError(f"y_split {y_t!r} must lie within the head's height ({lo:.4g} .. {hi:.4g}, the mesh's y): "
                         "it divides the upper face (under the headset) from the lower")
    return HFMModel(g, cfg, y_t)


def train_hfm(reg_dir, out_dir, cfg: HFMConfig | None = None, *, frames: slice | None = None,
              progress=None, log=print, callback=None, poses: str = "auto", device: str = "cpu") -> dict:
    """Register a person from an unoccluded video folder; saves ``out_dir`` (config.json,
    model.safetensors) and returns a summary (loss history, seconds, Gaussians, keys).
    ``poses``: the registration head poses (:func:`registration_poses`: the folder's file, or
    fitted to its landmarks).  ``device``: "cpu" or "cuda" (the gsplat rasteriser when installed,
    else the torch one on the GPU); the saved model is the same either way.
    ``callback(step, model, average)``, when given, runs after every step (``average``: the
    :class:`WeightAverage` once it has started, else None), e.g. to score the model as it trains."""
    from geoface.nn.losses import dssim
    from geoface.progress import progress as bar
    from geoface.hfm.data import load_video
    from geoface.splat.rasterizer import rasterize

    cfg = cfg or HFMConfig()
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    video = load_video(reg_dir, need_mesh=True, frames=frames)
    mesh = _head_mesh(video)
    pose_info = registration_poses(video, poses, log, mesh, fit=cfg.registration_landmarks)
    model = build_model(video, cfg, mesh)
    model.landmarks3d = pose_info.pop("landmarks3d")  # for the usage video's landmarks (hfm_usage.usage_poses)
    model.registration_size = (video.camera.width, video.camera.height)
    model.ict_identity = _ict_identity(reg_dir)  # a headset video is tracked as this person (hmd remove VIDEO)
    from geoface.nn.config import resolve_device

    dev = resolve_device(device, AvatarError) or "cpu"
    model.to(dev)
    refine = _PoseRefinement(video, model, cfg, dev) if cfg.pose_refine and pose_info["poses"] == "landmarks" else None
    targets = None
    if model.predicts_head_pose and refine is None:  # what mlp_head_pose learns to read from the crop
        R, tr, piv = video.poses
        targets = torch.tensor(np.stack([model.pose_params_of(R[f], tr[f], piv) for f in range(len(R))]),
                               dtype=torch.float32)
    cam = video.camera
    imgs, crops, boxes = (a.to(dev) for a in _frames_tensors(video, cfg.crop))
    if targets is not None:
        targets = targets.to(dev)
    vgg = None
    if cfg.lambda_vgg > 0:
        if cfg.vgg_weights:
            vgg = VGGPerceptual(cfg.vgg_weights).to(dev)
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
    bg = torch.zeros(3, device=dev)
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
        theta = model.encoder(crops[f:f + 1], boxes[f:f + 1])
        gd = refine.posed(theta, f) if refine is not None else model.deform(theta, frame_pose(video, f))
        rgb, alpha, depth, info = rasterize(gd, cam, background=bg, return_info=True)
        l1 = (rgb - gt).abs().mean()
        a, b = rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]
        ds = dssim(a, b)
        loss = (1 - cfg.lambda_rgb) * l1 + cfg.lambda_rgb * ds
        if vgg is not None:
            loss = loss + cfg.lambda_vgg * vgg(a, b)
        ls = boundary_loss(g.means[:, 1], strategy.upper if strategy is not None else model.upper_mask(),
                           model.y_split, cfg.split_margin)
        loss = loss + cfg.lambda_split * ls
        lp, loss_img = None, loss.detach()  # the history's "loss": the image (and split) terms
        if model.predicts_head_pose and it >= n_warm:
            target = targets[f] if refine is None else refine.target(f)
            lp = head_pose_loss(model, theta, target)
            loss = loss + cfg.lambda_pose * lp
        if strategy is not None:
            strategy.step_pre_backward(info)
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
        if refine is not None:
            start = n_warm // 2  # once the Gaussians have begun to fit the frames
            refine.step(f, (it - start) / max(1, cfg.iters - 1 - start) if it >= start else None)
        rec = {"step": it, "loss": float(loss_img), "l1": float(l1.detach()), "n": len(g), "nets": it >= n_warm}
        if lp is not None:
            rec["pose"] = float(lp.detach())
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
    if refine is not None:  # the usage calibration then learns the poses the avatar was fitted in
        pose_info.update(refine.finish())
    cal = calibrate_usage_poses(model, video, pose_info["poses"])
    pose_info["pose_calibration"] = len(cal["basis"]) if cal else 0
    model.cpu()
    seconds = time.perf_counter() - t0
    save_hfm(model, out_dir)
    if refine is not None:
        save_registration_poses(out_dir, *video.poses)
    else:  # a folder trained again without corrections keeps none of the last run's
        Path(out_dir, REGISTRATION_POSES).unlink(missing_ok=True)
    return {**pose_info, "seconds": seconds, "frames": len(imgs), "warmup_steps": n_warm,
            "averaged_steps": average.steps if average is not None else 0, "history": history, "n_gaussians": len(g), "n_upper": int(model.upper_mask().sum()),
            "dropped_children": strategy.dropped if strategy is not None else 0, "vgg": vgg is not None}


class _PoseRefinement:
    """Per-frame corrections of the registration poses fitted to landmarks, learned with the
    image loss (``HFMConfig.pose_refine``): landmarks that move with expressions tilt those
    poses by about half a degree, and the usage calibration would learn the tilt.

    Only the upper face (above y_t: forehead, eyes, nose bridge, hair) moves the corrections;
    the lower face is posed by them but passes them no gradient.  Corrections free to fit the
    whole image also fit what the lower face's deformation networks have not yet learned, frame
    by frame, and those then learn less (measured on a validation person: registration poses
    closer to the truth, the usage video 0.8 dB worse in the region the headset hides)."""

    def __init__(self, video, model: HFMModel, cfg: HFMConfig, dev):
        from geoface.avatar.corrections import FrameCorrections

        R, t, p = video.poses
        self.video, self.model = video, model
        self.R, self.t = (torch.tensor(np.asarray(a), dtype=torch.float32, device=dev) for a in (R, t))
        self.p = torch.tensor(np.asarray(p), dtype=torch.float32, device=dev)
        self.d_rot = torch.zeros(len(R), 3, device=dev, requires_grad=True)
        self.d_t = torch.zeros(len(R), 3, device=dev, requires_grad=True)  # metres, in the head's frame
        # translation steps: the rotation's step times the head's size
        self.opt = FrameCorrections([(self.d_rot, cfg.lr_pose), (self.d_t, cfg.lr_pose * 2 * float(model.scale))])

    def pose(self, f: int):
        from geoface.avatar.corrections import corrected_pose

        return corrected_pose(self.R[f], self.t[f], self.p, self.d_rot[f], self.d_t[f], self.model.center)

    def posed(self, theta: Tensor, f: int):
        """The model's Gaussians for latent ``theta`` in frame ``f``'s corrected pose, the
        correction's gradient reaching it through the upper face alone."""
        from geoface.splat.gaussians import GaussianTensors, quat_mul, rotmat_to_quat_torch

        g = self.model.deform(theta, None, read_pose=False)
        R, t, p = self.pose(f)
        Rd, td = R.detach(), t.detach()
        up = self.model.upper_mask()[:, None]
        means = torch.where(up, (g.means - p) @ R.T + p + t, (g.means - p) @ Rd.T + p + td)
        quats = quat_mul(rotmat_to_quat_torch(Rd[None]).expand(len(means), 4), g.quats)
        return GaussianTensors(means, g.log_scales, quats, g.opacity_logits, g.colors)

    def target(self, f: int) -> Tensor:
        """mlp_head_pose's target for frame ``f``: its corrected pose about the head's centre."""
        R, t, p = (a.detach().cpu().double().numpy() for a in self.pose(f))
        return torch.tensor(self.model.pose_params_of(R, t, p), dtype=torch.float32, device=self.R.device)

    def step(self, f: int, progress: float | None) -> None:
        """Move frame ``f``'s correction by its gradient; ``progress`` in [0, 1] through the
        corrections' steps (their rate falls tenfold, exponentially, so that they settle), None:
        not yet."""
        if progress is not None:
            self.opt.step(f, 0.1 ** min(max(progress, 0.0), 1.0))
        self.opt.zero_grad()

    @torch.no_grad()
    def finish(self) -> dict:
        """Set the video's poses to the corrected ones; the corrections' sizes (median, largest)."""
        poses = [self.pose(f) for f in range(len(self.R))]
        R = torch.stack([q[0] for q in poses]).double().cpu().numpy()
        t = torch.stack([q[1] for q in poses]).double().cpu().numpy()
        self.video.poses = (R, t, self.p.double().cpu().numpy())
        deg = np.degrees(self.d_rot.norm(dim=1).cpu().numpy())
        mm = 1000 * self.d_t.norm(dim=1).cpu().numpy()
        return {"pose_refined": True, "pose_correction_deg": [round(float(np.median(deg)), 3), round(float(deg.max()), 3)],
                "pose_correction_mm": [round(float(np.median(mm)), 2), round(float(mm.max()), 2)]}












