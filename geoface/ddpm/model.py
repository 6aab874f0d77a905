"""Text-guided DDPM on channel-stacked geometry images (position + normal + texture, 9 channels).

Model: diffusers ``UNet2DConditionModel`` with cross-attention in the down, middle and up blocks
(``CrossAttnDownBlock2D`` / ``UNetMidBlock2DCrossAttn`` / ``CrossAttnUpBlock2D``) attending to the
text encoder's token embeddings; ``DDPMScheduler(beta_schedule="squaredcos_cap_v2",
prediction_type="epsilon", clip_sample=False)``.  Geometry is not a photo: samples are **not**
clipped to [-1, 1] during denoising (clipping the x0 estimate would flatten heads whose
normalised coordinates touch the box); they are clamped once, at the very end, to [0, 1] when
turned into a geometry image.

Loss (eq. 12): ``L = sum_m mean |eps_m - eps_theta_m|`` over the modality groups m =
position (0-2), normal (3-5), texture (6-8).  **Unmasked**: the background is part of the image
(zeros), so the model also learns the coverage; at sampling the mask is ``|normal| > 0.5``.

Standardised data (beyond the paper; ``standardize=True``, the default): the UNet denoises
``(x - mean) / std`` (:class:`geoface.ddpm.data.DataStats`: the dataset's mean image and one
spread per modality), not ``x``.  Heads differ from one another by a few hundredths of the box,
so a model that denoises raw images must first learn the mean head to that precision before its
samples are surfaces at all; denoising the residual, its errors are scaled down by ``std``.
Measured on 1,000 ICT heads at 64² after an hour on a CPU: see ``docs/ddpm.md``.

Classifier-free guidance (beyond the paper, optional): with probability ``cfg_dropout`` a
training prompt is replaced by ``""``; sampling mixes ``eps_u + w (eps_c - eps_u)``.

The run's hyper-parameters are :mod:`geoface.ddpm.config`; its checkpoints (what a run
folder holds, loading a run for sampling) are :mod:`geoface.ddpm.checkpoint`.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from .checkpoint import STATS_FILE, DiffusionRun, load_run, save_checkpoint  # noqa: F401  (STATS_FILE: public here too)
from .checkpoint import load_st, load_state_dict, load_stats, optim_from_tensors
from .config import PREDICTIONS, PRESETS, DDPMConfig  # noqa: F401  (public here too)
from .diffusion import (EMA, PatchedUNet, build_scheduler, build_unet, ddpm_loss, ddpm_target,  # noqa: F401
                        learning_rate, shifted_cosine_betas)
from ..errors import CheckpointError

__all__ = ["DDPMConfig", "build_unet", "build_scheduler", "ddpm_loss", "EMA", "DiffusionRun",
           "train", "load_run", "sample", "MODALITY_SLICES", "PatchedUNet", "shifted_cosine_betas", "ddpm_target",
           "learning_rate"]

MODALITY_SLICES = {"position": slice(0, 3), "normal": slice(3, 6), "texture": slice(6, 9)}


# ---------------------------------------------------------------- training
def _embed(text, prompts: list[str]) -> torch.Tensor:
    return text.encode(prompts)  # [B, L, D]


def train(data_dir: str | os.PathLike, run_dir: str | os.PathLike, cfg: DDPMConfig, *,
          resume: bool = False, device: str | None = None, quiet: bool | None = None,
          text_encoder=None, max_seconds: float | None = None, loader_workers: int = 0,
          cache_mb: float = 256.0, gradient_checkpointing: bool = False, dataset=None) -> dict:
    """Train (or resume) a run; returns ``{"step", "loss", "losses", "steps_per_second"}`` of the last step.

    ``resume=True`` continues from ``RUN_DIR/checkpoint`` (its config wins over ``cfg`` except
    ``steps``, the new total).  ``max_seconds``: a wall-clock budget; training stops after the
    step that exceeds it and saves a checkpoint there.  Checkpoints every
    ``cfg.checkpoint_every`` steps.

    Data: items are read lazily (``cache_mb`` of decoded items kept, see
    :class:`geoface.ddpm.data.GImageDataset`) in one position frame for the whole dataset,
    stored in the checkpoint's ``state.json`` (``normalization``) and used to decode samples.
    Under ``accelerate launch`` each process draws from its own shard of the items with its
    own seed (:class:`geoface.ddpm.data.ShardSampler`); ``loader_workers`` processes decode
    items in the background (0 = in the training process).

    Progress: :class:`geoface.progress.StepProgress` (a bar on a terminal, a line every 10 s
    elsewhere) with steps/s, the time left and the loss.

    ``dataset``: train on this :class:`geoface.ddpm.data.GImageDataset`-like object (items,
    ``modalities``, ``channels``, ``prompts``, ``bbox_stats()``) instead of reading ``data_dir``.

    ``gradient_checkpointing``: recompute the UNet's activations in the backward pass instead
    of keeping them (less memory, about a third more time per step).
    """
    import time
    from accelerate import Accelerator
    from safetensors.torch import load_file  # noqa: F401  (fail early if missing)

    from geoface.progress import StepProgress, log

    from .data import GImageDataset, Normalization, ShardSampler, data_stats
    from .text import make_text_encoder

    run_dir = Path(run_dir)
    ckpt = run_dir / "checkpoint"
    start = 0
    state: dict = {}
    norm = None
    if resume and ckpt.is_dir():
        total = cfg.steps
        cfg = DDPMConfig.load(ckpt / "config.json")
        cfg.steps = total
        try:
            state = json.loads((ckpt / "state.json").read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise CheckpointError(f"{ckpt / 'state.json'} is missing or corrupt ({e})") from None
        if not isinstance(state, dict) or not isinstance(state.get("step"), int) or not isinstance(state.get("param_groups"), list):
            raise CheckpointError(f"{ckpt / 'state.json'}: needs an integer 'step' and a list 'param_groups'")
        if isinstance(state.get("normalization"), dict):  # keep the frame the run was trained in
            norm = Normalization.from_dict(state["normalization"])
    # the dataset first: a missing or corrupt one is reported before the text encoder loads
    ds = dataset if dataset is not None else GImageDataset(
        data_dir, res=cfg.res, augment=cfg.augment, seed=cfg.seed, normalization=norm,
        modalities=tuple(cfg.modalities) if resume and state else None, cache_mb=cache_mb)
    cfg.modalities = tuple(ds.modalities)
    cfg.channels = ds.channels
    stats = None
    if cfg.standardize:
        stats = (load_stats(ckpt) if resume and state
                 else data_stats(ds, seed=cfg.seed, quiet=quiet, per_pixel=cfg.stats_per_pixel))
    accel = Accelerator(cpu=(device in (None, "cpu")) and not torch.cuda.is_available() or device == "cpu")
    text = text_encoder or make_text_encoder(cfg.text_encoder, cache_dir=run_dir / "text_cache",
                                             max_length=cfg.text_max_length)
    cfg.cross_attention_dim = int(text.dim)
    torch.manual_seed(cfg.seed)
    unet = build_unet(cfg)
    if gradient_checkpointing:
        unet.enable_gradient_checkpointing()
    # one fused kernel per step on a GPU instead of a launch per parameter tensor
    fused = {"fused": True} if accel.device.type == "cuda" else {}
    opt = torch.optim.AdamW(unet.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, **fused)
    ema = EMA(unet, cfg.ema_decay)
    if resume and ckpt.is_dir():
        load_state_dict(unet, load_st(ckpt / "model.safetensors"), ckpt / "model.safetensors")
        ema.shadow = load_st(ckpt / "ema.safetensors")
        opt.load_state_dict(optim_from_tensors(load_st(ckpt / "optimizer.safetensors"), state["param_groups"]))
        start = int(state["step"])
    sched = build_scheduler(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    extra = {"data_dir": str(data_dir), **ds.bbox_stats(), "prompts": sorted(set(ds.prompts)), "items": len(ds)}
    unet, opt = accel.prepare(unet, opt)
    dev = accel.device
    rank, world = accel.process_index, accel.num_processes
    # each process: its own shard, its own data order, its own noise
    sampler = ShardSampler(len(ds), rank=rank, world=world, seed=cfg.seed, start=start * cfg.batch_size)
    loader = torch.utils.data.DataLoader(ds, batch_size=cfg.batch_size, sampler=sampler, num_workers=int(loader_workers),
                                         collate_fn=_collate, persistent_workers=loader_workers > 0)
    batches = iter(loader)
    g = torch.Generator().manual_seed((cfg.seed * 7_777 + start) * 1_000 + rank)
    empty = _embed(text, [""])
    last = {"step": start, "loss": float("nan"), "losses": {}, "steps_per_second": 0.0}
    t_start = time.perf_counter()
    params = sum(p.numel() for p in accel.unwrap_model(unet).parameters())
    log(f"ddpm train: {len(ds)} items ({', '.join(ds.modalities)}) at {cfg.res}x{cfg.res}, {params / 1e6:.1f} M parameters, "
        f"batch {cfg.batch_size}, steps {start}..{cfg.steps} on {dev}" + (f", {world} processes" if world > 1 else ""),
        quiet=quiet if accel.is_main_process else True)
    bar = StepProgress(cfg.steps, "ddpm train", start=start, quiet=quiet if accel.is_main_process else True,
                       budget=max_seconds)
    try:
        for step in range(start, cfg.steps):
            batch = next(batches)
            x0 = batch["image"].to(dev)
            if stats is not None:
                x0 = stats.forward(x0)
            prompts = batch["prompt"]
            cond = _embed(text, prompts)
            drop = torch.rand(len(prompts), generator=g) < cfg.cfg_dropout  # CFG: drop the prompt
            cond = torch.where(drop[:, None, None], empty.expand_as(cond), cond).to(dev)
            eps = torch.randn(x0.shape, generator=g).to(dev)
            t = torch.randint(0, cfg.num_train_timesteps, (x0.shape[0],), generator=g).to(dev)
            xt = sched.add_noise(x0, eps, t)  # q(x_t | x_0)
            unet.train()
            for group in opt.param_groups:
                group["lr"] = learning_rate(cfg, step)
            pred = unet(xt, t, encoder_hidden_states=cond).sample
            loss, parts = ddpm_loss(pred, ddpm_target(sched, x0, eps, t, cfg.prediction), cfg.modalities)
            opt.zero_grad(set_to_none=True)
            accel.backward(loss)
            opt.step()
            ema.update(accel.unwrap_model(unet), step)
            last = {"step": step + 1, "loss": float(loss.detach()), "losses": parts, "steps_per_second": bar.rate}
            bar.update(loss=last["loss"])
            out_of_time = max_seconds is not None and time.perf_counter() - t_start > max_seconds
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == cfg.steps or out_of_time:
                if accel.is_main_process:
                    save_checkpoint(ckpt, cfg, accel.unwrap_model(unet), ema, opt, step + 1, extra, stats)
            if out_of_time:
                break
    finally:
        bar.close()
        del batches
    last["steps_per_second"] = bar.rate
    if start >= cfg.steps and not ckpt.is_dir():
        save_checkpoint(ckpt, cfg, accel.unwrap_model(unet), ema, opt, start, extra, stats)
    return last


def _collate(items: list[dict]) -> dict:
    return {"image": torch.stack([it["image"] for it in items]), "mask": torch.stack([it["mask"] for it in items]),
            "prompt": [it["prompt"] for it in items], "index": [it["index"] for it in items]}


# ---------------------------------------------------------------- sampling
@torch.no_grad()
def sample(run: DiffusionRun, prompt: str, n: int = 4, steps: int = 50, scheduler: str = "ddim",
           guidance: float = 3.0, seed: int = 0, device: str = "cpu", quiet: bool | None = None,
           clip: float | None = 1.0) -> torch.Tensor:
    """Draw ``n`` samples ``[n, C, R, R]`` in the dataset's [-1, 1] frame (unclipped) for ``prompt``.

    Deterministic for a seed (a CPU ``torch.Generator`` drives all noise).  ``guidance`` is the
    classifier-free guidance weight (1 = plain conditional; <= 0 = unconditional).  ``clip``
    clamps each step's x0 estimate to ``clip`` times the data range ([-1, 1], or for a
    standardised run the largest standardised value of its data; None = off, see
    :func:`build_scheduler`).
    """
    from geoface.progress import progress
    cfg = run.config
    if clip is not None and clip > 0 and run.stats is not None:
        clip = float(clip) * float(run.stats.bound)
    sched = build_scheduler(cfg, scheduler, clip=clip)
    if not 1 <= int(steps) <= run.config.num_train_timesteps:
        raise CheckpointError(f"steps must be in 1..{run.config.num_train_timesteps} (the run was trained with "
                              f"{run.config.num_train_timesteps} noise levels); got {steps}")
    sched.set_timesteps(int(steps))
    unet = run.unet.to(device).eval()
    g = torch.Generator().manual_seed(int(seed))
    x = torch.randn((n, cfg.channels, cfg.res, cfg.res), generator=g).to(device)
    cond = _embed(run.text, [prompt] * n).to(device)
    unc = _embed(run.text, [""] * n).to(device)
    for t in progress(sched.timesteps, "ddpm sample", quiet=quiet):
        if guidance == 1.0:
            eps = unet(x, t, encoder_hidden_states=cond).sample
        elif guidance <= 0:
            eps = unet(x, t, encoder_hidden_states=unc).sample
        else:
            e = unet(torch.cat([x, x]), t, encoder_hidden_states=torch.cat([unc, cond])).sample
            eu, ec = e.chunk(2)
            eps = eu + guidance * (ec - eu)
        kw = {"generator": g} if scheduler == "ddpm" else {}
        x = sched.step(eps.cpu(), t, x.cpu(), **kw).prev_sample.to(device)
    x = x.cpu()
    return run.stats.inverse(x) if run.stats is not None else x


def to_geometry_images(x: torch.Tensor, state: dict, support=None) -> list:
    """Samples ``[n, C, R, R]`` → :class:`geoface.gimage.GeometryImage` (clamped to [0, 1] here),
    positions in mesh units through the run's dataset normalisation (``state``'s box).

    The coverage mask is ``|normal| > 0.5``; ``support`` (a boolean ``[R, R]``, e.g. the pixels
    that every training item covers) adds pixels known to be covered whatever the sample's
    normal length there."""
    import numpy as np

    from geoface.gimage import GeometryImage
    from geoface.gimage.image import FORMAT_VERSION, MODALITIES
    mods = list(state.get("modalities") or ["position", "normal", "texture"][: x.shape[1] // 3])
    if 3 * len(mods) != x.shape[1]:
        raise CheckpointError(f"samples have {x.shape[1]} channels; the run's modalities are {mods}")
    out = []
    for s in x:
        img = ((s.float() + 1) / 2).clamp(0, 1).numpy().astype(np.float32)
        nrm = s[3:6].float()
        mask = (nrm.norm(dim=0) > 0.5).numpy()
        if support is not None:
            mask = mask | np.asarray(support, bool)
        img = img * mask[None]
        meta = {"bbox_min": list(state["bbox_min"]), "bbox_max": list(state["bbox_max"]),
                "channels": [c for m in mods for c in MODALITIES[m]],
                "resolution": int(img.shape[-1]), "version": FORMAT_VERSION, "align_corners": True, "source": "geoface.ddpm.model"}
        if "normalization" in state:
            meta["normalization"] = state["normalization"]
        out.append(GeometryImage(img, mask, meta))
    return out
