"""Saved avatar model folders (``config.json`` + ``model.safetensors``), shared by HFM-GS and
THGS: atomic writes, validated reads, weights without pickle."""
from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from geoface.splat.errors import SplatError

__all__ = ["write_model_dir", "read_model_dir", "read_model_config"]


def load_model_state(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise SplatError(f"{path}: no such weights file")
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file
            return load_file(str(path))
        sd = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as e:  # corrupt or not a weights file
        raise SplatError(f"{path}: cannot read weights ({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None
    if not isinstance(sd, dict):
        raise SplatError(f"{path}: not a state dict")
    return sd


def write_model_dir(out_dir, module: nn.Module, meta: dict) -> Path:
    """``out_dir/model.safetensors`` (the module's state, written to a temporary name first) and
    ``out_dir/config.json`` (``meta``). Shared by the avatar models."""
    from safetensors.torch import save_file

    from geoface._io import atomic_path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().contiguous().cpu() for k, v in module.state_dict().items() if v is not None}
    with atomic_path(out / "model.safetensors") as tmp:
        save_file(sd, str(tmp))
    (out / "config.json").write_text(json.dumps(meta, indent=1))
    return out


def read_model_dir(model_dir, fmt: str, what: str) -> tuple[Path, dict, dict]:
    """(folder, config.json, state dict) of a model folder written by :func:`write_model_dir`
    whose config says ``"format": fmt``; any problem is a one-line SplatError."""
    d, meta = read_model_config(model_dir, fmt, what)
    return d, meta, load_model_state(d / "model.safetensors")


def read_model_config(model_dir, fmt: str, what: str) -> tuple[Path, dict]:
    """(folder, config.json) of a model folder, validated (format, version, a ``config``
    object) before any weights are read; problems are :class:`ModelFolderError`."""
    from geoface.nn.config import check_version

    from geoface.splat.errors import ModelFolderError

    d = Path(model_dir)
    try:
        meta = json.loads((d / "config.json").read_text())
    except (OSError, ValueError) as e:
        raise ModelFolderError(f"{d}: not a {what} model folder (config.json: {type(e).__name__})") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        raise ModelFolderError(f"{d}/config.json: not a {what} model")
    check_version(meta, 1, where=f"{d}/config.json", error=ModelFolderError)
    if not isinstance(meta.get("config"), dict):
        raise ModelFolderError(f"{d}/config.json: 'config' must be a JSON object")
    return d, meta
