"""The avatar contract, shared by HFM-GS and THGS: saved model folders (``config.json`` +
``model.safetensors``: atomic writes, validated reads, weights without pickle), the
:class:`AvatarModel` protocol every avatar model class follows (found by the ``format`` of its
``config.json``, :func:`geoface.drive.avatars.avatar_formats`), and :class:`AvatarDrive`, an avatar
frame by frame."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, ClassVar, Protocol, runtime_checkable

import numpy as np

import torch
from torch import nn

from geoface.errors import AvatarError

__all__ = ["AvatarModel", "AvatarAdapter", "AvatarDrive", "uint8_frames", "write_model_dir", "read_model_dir", "read_model_config"]


@dataclass
class AvatarDrive:
    """A trained avatar and what drives it: ``gaussians(t)`` for t in ``range(n_frames)``;
    ``frames`` (uint8 [T, H, W, 3]) are the video's own frames when there is a video."""

    n_frames: int
    fps: float
    what: str
    model_kind: str
    _gaussians: Callable
    frames: np.ndarray | None = None

    @torch.no_grad()
    def gaussians(self, t: int):
        if not 0 <= int(t) < self.n_frames:
            raise AvatarError(f"frame {t} is outside 0..{self.n_frames - 1}")
        return self._gaussians(int(t))


def uint8_frames(frames) -> np.ndarray:
    """Frames in [0, 1] as uint8 (what :class:`AvatarDrive` shows beside the avatar)."""
    return np.round(np.clip(np.asarray(frames, np.float32), 0, 1) * 255).astype(np.uint8)


@runtime_checkable
class AvatarModel(Protocol):
    """What every avatar model class gives (:class:`geoface.hfm.model.HFMModel`,
    :class:`geoface.thgs.model.THGSModel`): ``FORMAT``, the ``format`` its ``config.json`` names;
    ``KIND``, the verb group that trains it (``"hfm"``: ``geoface hmd``, ``"thgs"``: ``geoface
    talk``); ``load``/``save`` of a model folder; ``drive``, the avatar frame by frame from what
    drives it (``source``: a file or folder; None where the model has a rest pose)."""

    FORMAT: ClassVar[str]
    KIND: ClassVar[str]

    @classmethod
    def load(cls, model_dir) -> "AvatarModel": ...

    def save(self, out_dir) -> None: ...

    def drive(self, source, *, fps: float = 25.0) -> AvatarDrive: ...


def load_model_state(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise AvatarError(f"{path}: no such weights file")
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file
            return load_file(str(path))
        sd = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as e:  # corrupt or not a weights file
        raise AvatarError(f"{path}: cannot read weights ({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None
    if not isinstance(sd, dict):
        raise AvatarError(f"{path}: not a state dict")
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
    whose config says ``"format": fmt``; any problem is a one-line AvatarError."""
    d, meta = read_model_config(model_dir, fmt, what)
    return d, meta, load_model_state(d / "model.safetensors")


def read_model_config(model_dir, fmt: str, what: str) -> tuple[Path, dict]:
    """(folder, config.json) of a model folder, validated (format, version, a ``config``
    object) before any weights are read; problems are :class:`ModelFolderError`."""
    from geoface.nn.config import check_version

    from geoface.errors import ModelFolderError

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


class AvatarAdapter:
    """A trained avatar network under :class:`AvatarModel`: a subclass names ``FORMAT``, ``KIND``
    and its package's ``_load(model_dir)``, ``_save(model, out_dir)`` and ``_drive(model, source,
    fps=)`` (as staticmethods); ``model`` is the network."""

    FORMAT: ClassVar[str]
    KIND: ClassVar[str]
    _load: ClassVar[Callable]
    _save: ClassVar[Callable]
    _drive: ClassVar[Callable]

    def __init__(self, model):
        self.model = model

    @classmethod
    def load(cls, model_dir):
        return cls(cls._load(model_dir))

    def save(self, out_dir) -> None:
        type(self)._save(self.model, out_dir)

    def drive(self, source, *, fps: float = 25.0) -> AvatarDrive:
        return type(self)._drive(self.model, source, fps=fps)

