"""Checkpoints of a text-guided DDPM run (:mod:`geoface.ddpm.model`): writing one atomically,
loading a run for sampling (:class:`DiffusionRun`), and checking what is read.

Checkpoints (``RUN_DIR/checkpoint/``): ``config.json``, ``model.safetensors``,
``ema.safetensors``, ``optimizer.safetensors``, ``data_stats.safetensors`` (when standardised) +
``state.json`` (step, optimizer param groups, RNG seed, data bbox).  No pickle anywhere.
"""
from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import torch

from .config import DDPMConfig
from .diffusion import EMA, build_unet
from ..errors import CheckpointError

STATS_FILE = "data_stats.safetensors"


def optim_to_tensors(opt: torch.optim.Optimizer) -> tuple[dict, list]:
    sd = opt.state_dict()
    tensors = {}
    for pid, st in sd["state"].items():
        for k, v in st.items():
            tensors[f"{pid}.{k}"] = (v if torch.is_tensor(v) else torch.tensor(v)).contiguous()
    return tensors, sd["param_groups"]


def optim_from_tensors(tensors: dict, groups: list) -> dict:
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
        ot, groups = optim_to_tensors(opt)
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


def load_st(path: Path) -> dict:
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
    data standardisation (:class:`geoface.ddpm.data.DataStats`; None for a run without)."""
    config: DDPMConfig
    unet: torch.nn.Module
    text: object
    state: dict = field(default_factory=dict)
    stats: object = None


def load_state_dict(model, sd: dict, path: Path) -> None:
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
    load_state_dict(unet, load_st(f), f)
    unet.eval()
    try:
        state = json.loads((ckpt / "state.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, RecursionError) as e:
        raise CheckpointError(f"{ckpt / 'state.json'} is missing or corrupt ({type(e).__name__})") from None
    check_state(state, ckpt / "state.json")
    stats = load_stats(ckpt) if cfg.standardize else None
    if text_encoder is None:
        from .text import make_text_encoder
        text_encoder = make_text_encoder(cfg.text_encoder, max_length=cfg.text_max_length)
    dim = getattr(text_encoder, "dim", None)
    if dim is not None and int(dim) != int(cfg.cross_attention_dim):
        raise CheckpointError(f"{ckpt / 'config.json'}: the text encoder {cfg.text_encoder!r} gives {int(dim)}-dimensional "
                              f"embeddings, the model was trained on {int(cfg.cross_attention_dim)} (cross_attention_dim)")
    return DiffusionRun(cfg, unet, text_encoder, state, stats)


def check_state(state, where: Path) -> None:
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


def load_stats(ckpt: Path):
    from geoface.errors import GeofaceError

    from .data import DataStats
    f = ckpt / STATS_FILE
    if not f.is_file():
        raise CheckpointError(f"missing {STATS_FILE} in {ckpt} (the run's config says its data are standardised)")
    try:
        return DataStats.load(f)
    except GeofaceError as e:
        raise CheckpointError(str(e)) from None
