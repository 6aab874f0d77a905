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
``(x - mean) / std`` (:class:`geoface.learn.data.DataStats`: the dataset's mean image and one
spread per modality), not ``x``.  Heads differ from one another by a few hundredths of the box,
so a model that denoises raw images must first learn the mean head to that precision before its
samples are surfaces at all; denoising the residual, its errors are scaled down by ``std``.
Measured on 1,000 ICT heads at 64² after an hour on a CPU: see ``docs/ddpm.md``.

Classifier-free guidance (beyond the paper, optional): with probability ``cfg_dropout`` a
training prompt is replaced by ``""``; sampling mixes ``eps_u + w (eps_c - eps_u)``.

Checkpoints (``RUN_DIR/checkpoint/``): ``config.json``, ``model.safetensors``,
``ema.safetensors``, ``optimizer.safetensors``, ``data_stats.safetensors`` (when standardised) +
``state.json`` (step, optimizer param groups, RNG seed, data bbox).  No pickle anywhere.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import torch

from .._io import atomic_write_text
from .diffusion import (EMA, PatchedUNet, build_scheduler, build_unet, ddpm_loss, ddpm_target,  # noqa: F401
                        learning_rate, shifted_cosine_betas)
from .errors import CheckpointError

__all__ = ["DDPMConfig", "build_unet", "build_scheduler", "ddpm_loss", "EMA", "DiffusionRun",
           "train", "load_run", "sample", "MODALITY_SLICES", "PatchedUNet", "shifted_cosine_betas", "ddpm_target",
           "learning_rate"]

MODALITY_SLICES = {"position": slice(0, 3), "normal": slice(3, 6), "texture": slice(6, 9)}
STATS_FILE = "data_stats.safetensors"
PREDICTIONS = ("epsilon", "v_prediction", "sample")


@dataclass
class DDPMConfig:
    """All hyper-parameters of a run; saved as ``config.json``."""
    res: int = 64
    channels: int = 9
    block_out_channels: tuple = (64, 128, 256)
    layers_per_block: int = 2
    attention_head_dim: int = 8
    norm_num_groups: int = 32
    # levels (0 = full resolution) whose down/up blocks have cross-attention; None = all but the
    # coarsest (the original layout).  Self-attention at 64x64 costs 4096^2 per head: on a CPU
    # use e.g. (2, 3) with four levels.  The middle block always has cross-attention.
    attention_levels: tuple | None = None
    text_encoder: str = "minilm"       # minilm | clip:PATH | hash[:DIM]
    text_max_length: int = 32
    cross_attention_dim: int = 384     # = text encoder dim (filled in at train time)
    num_train_timesteps: int = 1000
    cfg_dropout: float = 0.1
    lr: float = 1e-4
    weight_decay: float = 1e-2
    ema_decay: float = 0.999
    batch_size: int = 8
    steps: int = 10000
    checkpoint_every: int = 500
    augment: bool = True
    seed: int = 0
    # the stacked modalities (channels = 3 per modality); a dataset without texture trains on
    # position + normal (6 channels)
    modalities: tuple[str, ...] = ("position", "normal", "texture")
    # denoise (x - mean image) / std per modality (module docs); configs written before this
    # option existed load with False
    standardize: bool = True
    # what the UNet predicts: "epsilon" (the paper), "v_prediction" or "sample" (x0)
    prediction: str = "epsilon"
    # the UNet sees ``patch x patch`` pixel blocks folded into channels (pixel unshuffle): a 64²
    # image is denoised by a 32² network with 4x the channels (simple diffusion's patching)
    patch: int = 1
    # noise-schedule shift (simple diffusion): the cosine schedule's log-SNR lowered by
    # 2 log(shift), so that a 64² image is as noisy at step t as a 32² one with shift 2
    schedule_shift: float = 1.0
    # standardise by one spread per modality and pixel (DataStats) instead of one per modality
    stats_per_pixel: bool = False
    # "constant", or "cosine": the learning rate falls from lr to lr/10 over ``steps``
    lr_schedule: str = "constant"

    def __post_init__(self):
        from geoface.nn.config import check_ranges

        def need(ok, what, value):
            if not ok:
                raise CheckpointError(f"{what}; got {value!r}")

        check_ranges(self, ints={"res": (4, 8192), "channels": (1, 4096), "layers_per_block": (1, 64),
                                 "attention_head_dim": (1, 4096), "norm_num_groups": (1, 4096),
                                 "text_max_length": (1, 4096), "cross_attention_dim": (1, 65536),
                                 "num_train_timesteps": (2, 1_000_000), "batch_size": (1, 1 << 20),
                                 "steps": (0, 1 << 40), "checkpoint_every": (1, 1 << 40)},
                     reals={"cfg_dropout": (0.0, 1.0, False, False), "lr": (0.0, 10.0, True, False),
                            "weight_decay": (0.0, 100.0, False, False), "ema_decay": (0.0, 1.0, False, True)})
        boc = self.block_out_channels
        need(isinstance(boc, (tuple, list)) and 1 <= len(boc) <= 12
             and all(isinstance(c, int) and not isinstance(c, bool) and 1 <= c <= 65536 for c in boc),
             "block_out_channels must be 1 to 12 positive integers", boc)
        need(all(c % self.norm_num_groups == 0 for c in boc),
             f"every block_out_channels entry must be a multiple of norm_num_groups ({self.norm_num_groups})", boc)
        if self.attention_levels is not None:
            lv = self.attention_levels
            need(isinstance(lv, (tuple, list)) and all(isinstance(k, int) and 0 <= k < len(boc) for k in lv),
                 f"attention_levels must be levels in 0..{len(boc) - 1}", lv)
        need(isinstance(self.modalities, (tuple, list)) and 1 <= len(self.modalities) <= 8
             and all(isinstance(m, str) for m in self.modalities) and len(set(self.modalities)) == len(self.modalities),
             "modalities must be distinct modality names", self.modalities)
        if self.prediction not in PREDICTIONS:
            raise CheckpointError(f"prediction must be one of {', '.join(PREDICTIONS)}; got {self.prediction!r}")
        if int(self.patch) < 1 or int(self.res) % int(self.patch):
            raise CheckpointError(f"patch must be a positive divisor of res {self.res}; got {self.patch}")
        if self.lr_schedule not in ("constant", "cosine"):
            raise CheckpointError(f"lr_schedule must be 'constant' or 'cosine'; got {self.lr_schedule!r}")
        if not float(self.schedule_shift) > 0:
            raise CheckpointError(f"schedule_shift must be positive; got {self.schedule_shift}")

    @classmethod
    def preset(cls, name: str = "small", **overrides) -> "DDPMConfig":
        """A named model size (:data:`PRESETS`) with ``overrides`` applied."""
        if name not in PRESETS:
            raise CheckpointError(f"unknown model preset {name!r}; presets are {', '.join(PRESETS)}")
        kw = {**PRESETS[name], **overrides}
        if kw.get("attention_levels") == "coarse":
            # self-attention only where the feature map is 16x16 or coarser (and at most the two
            # coarsest levels): its memory grows with the fourth power of the side
            n, res = len(kw["block_out_channels"]), int(kw.get("res", cls.res)) // int(kw.get("patch", 1))
            kw["attention_levels"] = tuple(k for k in range(max(0, n - 2), n) if res >> k <= 16) or (n - 1,)
        return cls(**kw)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict, where: str = "config.json") -> "DDPMConfig":
        from geoface.nn.config import config_from_dict

        if isinstance(d, dict) and "standardize" not in d:  # a run from before standardisation
            d = {**d, "standardize": False}
        return config_from_dict(cls, d, where=where)

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_text(path, self.to_json())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "DDPMConfig":
        path = Path(path)
        if not path.is_file():
            raise CheckpointError(f"missing {path.name} in {path.parent}")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise CheckpointError(f"{path} is not a valid config ({e})") from None
        return cls.from_dict(d, where=str(path))


#: named model sizes.  ``small`` (the command line's default, 5.9 M parameters at 32² and 64² with a
#: 384-d text encoder) is the one the README's results are measured with; ``base`` is the
#: paper-sized layout (for a GPU); ``tiny`` is for smoke tests.  ``attention_levels="coarse"``:
#: self-attention on the feature maps of 16² and coarser among the two coarsest levels.
PRESETS = {
    "tiny": dict(block_out_channels=(16, 32), layers_per_block=1, attention_head_dim=8, norm_num_groups=8,
                 attention_levels=(1,)),
    "small": dict(block_out_channels=(32, 64, 96, 128), layers_per_block=1, attention_head_dim=8, norm_num_groups=8,
                  attention_levels="coarse", lr=3e-4, ema_decay=0.995),
    "base": dict(block_out_channels=(64, 128, 256, 256), layers_per_block=2, attention_head_dim=8, norm_num_groups=32,
                 attention_levels=(1, 2, 3), lr=1e-4, ema_decay=0.999),
}


# ---------------------------------------------------------------- checkpoints
def _optim_to_tensors(opt: torch.optim.Optimizer) -> tuple[dict, list]:
    sd = opt.state_dict()
    tensors = {}
    for pid, st in sd["state"].items():
        for k, v in st.items():
            tensors[f"{pid}.{k}"] = (v if torch.is_tensor(v) else torch.tensor(v)).contiguous()
    return tensors, sd["param_groups"]


def _optim_from_tensors(tensors: dict, groups: list) -> dict:
    state: dict = {}
    for name, v in tensors.items():
        pid, k = name.split(".", 1)
        state.setdefault(int(pid), {})[k] = v
    return {"state": state, "param_groups": groups}


def save_checkpoint(ckpt: Path, cfg: DDPMConfig, model, ema: EMA, opt, step: int, extra: dict, stats=None) -> None:
    """Write a complete checkpoint folder atomically (temp folder + rename)."""
    from safetensors.torch import save_file
    ckpt = Path(ckpt)
    tmp = ckpt.with_name(f".{ckpt.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        cfg.save(tmp / "config.json")
        cpu = lambda d: {k: v.detach().cpu().contiguous() for k, v in d.items()}  # noqa: E731
        save_file(cpu(model.state_dict()), str(tmp / "model.safetensors"))
        save_file(cpu(ema.shadow), str(tmp / "ema.safetensors"))
        ot, groups = _optim_to_tensors(opt)
        save_file(cpu(ot), str(tmp / "optimizer.safetensors"))
        if stats is not None:
            stats.save(tmp / STATS_FILE)
        (tmp / "state.json").write_text(json.dumps({"step": step, "param_groups": groups, **extra}), encoding="utf-8")
    except Exception as e:  # a full disk: OSError, or safetensors' own error type
        shutil.rmtree(tmp, ignore_errors=True)
        msg = getattr(e, "strerror", None) or (str(e).splitlines()[0][:160] if str(e) else type(e).__name__)
        raise CheckpointError(f"{ckpt}: could not write the checkpoint ({msg}); an earlier one is kept") from None
    from .._io import chmod_tree

    chmod_tree(tmp)  # the user's umask (safetensors writes 0600)
    old = ckpt.with_name(f".{ckpt.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if ckpt.exists():
        os.replace(ckpt, old)
    os.replace(tmp, ckpt)
    shutil.rmtree(old, ignore_errors=True)


def _load_st(path: Path) -> dict:
    from safetensors.torch import load_file
    if not path.is_file():
        raise CheckpointError(f"missing {path.name} in {path.parent}")
    try:
        return load_file(str(path))
    except Exception as e:
        raise CheckpointError(f"{path} is corrupt or truncated ({type(e).__name__}: {e})") from None


@dataclass
class DiffusionRun:
    """A loaded run: config, UNet (EMA weights when ``use_ema``), text encoder, state and the
    data standardisation (:class:`geoface.learn.data.DataStats`; None for a run without)."""
    config: DDPMConfig
    unet: torch.nn.Module
    text: object
    state: dict = field(default_factory=dict)
    stats: object = None


def _load_state_dict(model, sd: dict, path: Path) -> None:
    try:
        model.load_state_dict(sd, strict=True)
    except RuntimeError as e:
        raise CheckpointError(f"{path} does not match config.json: {str(e).splitlines()[0]}") from None


def load_run(run_dir: str | os.PathLike, use_ema: bool = True, text_encoder=None) -> DiffusionRun:
    """Load ``RUN_DIR/checkpoint`` (or a checkpoint folder itself) for sampling."""
    run_dir = Path(run_dir)
    ckpt = run_dir / "checkpoint" if (run_dir / "checkpoint").is_dir() else run_dir
    if not ckpt.is_dir():
        raise CheckpointError(f"no checkpoint folder in {run_dir}")
    cfg = DDPMConfig.load(ckpt / "config.json")
    unet = build_unet(cfg)
    f = ckpt / ("ema.safetensors" if use_ema else "model.safetensors")
    _load_state_dict(unet, _load_st(f), f)
    unet.eval()
    try:
        state = json.loads((ckpt / "state.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, RecursionError) as e:
        raise CheckpointError(f"{ckpt / 'state.json'} is missing or corrupt ({type(e).__name__})") from None
    _check_state(state, ckpt / "state.json")
    stats = _load_stats(ckpt) if cfg.standardize else None
    if text_encoder is None:
        from .text import make_text_encoder
        text_encoder = make_text_encoder(cfg.text_encoder, max_length=cfg.text_max_length)
    return DiffusionRun(cfg, unet, text_encoder, state, stats)


def _check_state(state, where: Path) -> None:
    """A checkpoint's ``state.json``: a JSON object with a step and the data's box (finite,
    ``bbox_max > bbox_min`` per axis), which sampling decodes positions with."""
    import math

    if not isinstance(state, dict):
        raise CheckpointError(f"{where}: must be a JSON object; got {type(state).__name__}")
    step = state.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise CheckpointError(f"{where}: needs a non-negative integer 'step'; got {step!r}"[:200])
    lo, hi = state.get("bbox_min"), state.get("bbox_max")
    ok = all(isinstance(b, list) and len(b) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                          and math.isfinite(x) for x in b) for b in (lo, hi))
    if not ok or not all(b > a for a, b in zip(lo, hi)):
        raise CheckpointError(f"{where}: 'bbox_min' and 'bbox_max' must be 3 finite numbers each, max above min; "
                              f"got {lo!r} and {hi!r}"[:300])


def _load_stats(ckpt: Path):
    from geoface.errors import GeofaceError

    from .data import DataStats
    f = ckpt / STATS_FILE
    if not f.is_file():
        raise CheckpointError(f"missing {STATS_FILE} in {ckpt} (the run's config says its data are standardised)")
    try:
        return DataStats.load(f)
    except GeofaceError as e:
        raise CheckpointError(str(e)) from None


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
    :class:`geoface.learn.data.GImageDataset`) in one position frame for the whole dataset,
    stored in the checkpoint's ``state.json`` (``normalization``) and used to decode samples.
    Under ``accelerate launch`` each process draws from its own shard of the items with its
    own seed (:class:`geoface.learn.data.ShardSampler`); ``loader_workers`` processes decode
    items in the background (0 = in the training process).

    Progress: :class:`geoface.progress.StepProgress` (a bar on a terminal, a line every 10 s
    elsewhere) with steps/s, the time left and the loss.

    ``dataset``: train on this :class:`geoface.learn.data.GImageDataset`-like object (items,
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
        stats = (_load_stats(ckpt) if resume and state
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
        _load_state_dict(unet, _load_st(ckpt / "model.safetensors"), ckpt / "model.safetensors")
        ema.shadow = _load_st(ckpt / "ema.safetensors")
        opt.load_state_dict(_optim_from_tensors(_load_st(ckpt / "optimizer.safetensors"), state["param_groups"]))
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
                "resolution": int(img.shape[-1]), "version": FORMAT_VERSION, "align_corners": True, "source": "geoface.learn.ddpm"}
        if "normalization" in state:
            meta["normalization"] = state["normalization"]
        out.append(GeometryImage(img, mask, meta))
    return out
