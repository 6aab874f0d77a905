"""Torch dataset over geometry-image folders (the dataset builder's output or any folder tree).

Each item is a dict:

* ``image``  ``[9, R, R]`` float32: position, normal, texture channels stacked, scaled from
  [0, 1] to [-1, 1]; uncovered pixels are 0.
* ``mask``   ``[1, R, R]`` float32 coverage (1 = valid pixel).
* ``prompt`` str (``""`` when none is known).
* ``index``  int.

Sources: ``DATA_DIR/manifest.jsonl`` (see :mod:`geoface.dataset`: rows with ``status == "ok"``,
item folder ``DATA_DIR/<item>``, optional ``prompt``; the last row of an item wins) or, with no
manifest, every folder below ``DATA_DIR`` holding a ``meta.json`` (prompt from
``meta["prompt"]`` if present).

Augmentation (seeded; the paper's rigid augmentation) acts in the **normalised** [-1, 1]
position space (per-axis bbox), so it is rigid there, not necessarily in mesh units: a random
rotation about the vertical (y) axis by up to ``max_angle`` degrees, a uniform scale in
``scale_range`` and a translation up to ``max_shift``; normals get the same rotation and stay
unit. Values may leave [-1, 1] slightly; they are not clipped.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from geoface.errors import GeofaceError

__all__ = ["GImageDataset", "AugmentOptions", "find_items", "area_resize", "rigid_augment", "CHANNELS"]

CHANNELS = ("position", "normal", "texture")


@dataclass(frozen=True)
class AugmentOptions:
    max_angle: float = 30.0          # degrees, rotation about +y
    max_shift: float = 0.05          # translation, normalised units
    scale_range: tuple = (0.9, 1.0)  # uniform scale


def find_items(data_dir: str | os.PathLike) -> list[tuple[Path, str]]:
    """``(folder, prompt)`` pairs in a stable (sorted) order."""
    root = Path(data_dir)
    if not root.is_dir():
        raise GeofaceError(f"data folder not found: {root}")
    man = root / "manifest.jsonl"
    items: list[tuple[Path, str]] = []
    if man.is_file():
        last: dict[str, dict] = {}
        try:
            text = man.read_bytes().decode("utf-8")
        except UnicodeDecodeError:
            raise GeofaceError(f"{man} is not a text file (not UTF-8)") from None
        for n, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError as e:
                raise GeofaceError(f"{man}: line {n} is not JSON ({e})") from None
            if not isinstance(row, dict):
                raise GeofaceError(f"{man}: line {n} is not a JSON object")
            if isinstance(row.get("item"), str):
                last[row["item"]] = row
        for name in sorted(last):
            row = last[name]
            folder = root / name
            if row.get("status") == "ok" and (folder / "meta.json").is_file():
                items.append((folder, str(row.get("prompt") or "")))
    else:
        for meta in sorted(root.rglob("meta.json")):
            try:
                m = json.loads(meta.read_text(encoding="utf-8"))
                prompt = str(m.get("prompt") or "") if isinstance(m, dict) else ""
            except (OSError, json.JSONDecodeError, UnicodeDecodeError):
                prompt = ""
            items.append((meta.parent, prompt))
    if not items:
        raise GeofaceError(f"no geometry images found in {root} (need manifest.jsonl rows with status 'ok' "
                           "or folders with meta.json)")
    return items


def area_resize(image: np.ndarray, mask: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Downsample ``image (C, N, N)`` by averaging the *valid* pixels of each block (N % res == 0)."""
    C, N, _ = image.shape
    if res == N:
        return image, mask
    if res > N or N % res:
        raise GeofaceError(f"training resolution {res} must divide the image resolution {N}")
    k = N // res
    m = mask.astype(np.float32).reshape(res, k, res, k)
    s = (image * mask).reshape(C, res, k, res, k).sum(axis=(2, 4))
    cnt = m.sum(axis=(1, 3))
    out = np.where(cnt > 0, s / np.maximum(cnt, 1), 0.0).astype(np.float32)
    return out, cnt > 0


def rigid_augment(x: torch.Tensor, mask: torch.Tensor, gen: torch.Generator,
                  opts: AugmentOptions = AugmentOptions()) -> torch.Tensor:
    """Rotate/scale/shift positions (channels 0-2) and rotate normals (3-5) of ``x [9, R, R]`` in [-1, 1]."""
    u = torch.rand(5, generator=gen, dtype=torch.float64)
    a = math.radians(opts.max_angle) * (2 * float(u[0]) - 1)
    lo, hi = opts.scale_range
    s = lo + (hi - lo) * float(u[1])
    t = torch.tensor([opts.max_shift * (2 * float(u[i]) - 1) for i in (2, 3, 4)], dtype=torch.float32)
    c, sn = math.cos(a), math.sin(a)
    R = torch.tensor([[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]], dtype=torch.float32)
    y = x.clone()
    p = torch.einsum("ij,jhw->ihw", R, x[0:3]) * s + t[:, None, None]
    n = torch.einsum("ij,jhw->ihw", R, x[3:6])
    m = mask.to(x.dtype)
    y[0:3] = p * m
    y[3:6] = n * m
    return y


class GImageDataset(torch.utils.data.Dataset):
    """Geometry images as ``[9, R, R]`` tensors in [-1, 1] + mask + prompt (see module doc)."""

    def __init__(self, data_dir: str | os.PathLike, res: int | None = None, augment: bool = False,
                 seed: int = 0, augment_options: AugmentOptions = AugmentOptions(), preload: bool = True):
        self.items = find_items(data_dir)
        self.res, self.augment, self.seed, self.aug_opts = res, augment, int(seed), augment_options
        self.epoch = 0
        self._cache: dict[int, tuple[torch.Tensor, torch.Tensor, dict]] = {}
        if preload:
            for i in range(len(self.items)):
                self._load(i)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def prompts(self) -> list[str]:
        return [p for _, p in self.items]

    def _load(self, i: int):
        if i not in self._cache:
            from geoface.gimage import load_gimage
            gi = load_gimage(self.items[i][0])
            img = np.concatenate([gi.modality(m) for m in CHANNELS], axis=0).astype(np.float32)
            mask = np.asarray(gi.mask, bool)
            if self.res is not None:
                img, mask = area_resize(img, mask, int(self.res))
            x = torch.from_numpy(img * 2.0 - 1.0) * torch.from_numpy(mask.astype(np.float32))
            self._cache[i] = (x, torch.from_numpy(mask.astype(np.float32))[None], gi.meta)
        return self._cache[i]

    def meta(self, i: int) -> dict:
        return self._load(i)[2]

    def bbox_stats(self) -> dict:
        """Union bbox of all items (for turning samples back into meshes)."""
        lo = np.min([self.meta(i)["bbox_min"] for i in range(len(self))], axis=0)
        hi = np.max([self.meta(i)["bbox_max"] for i in range(len(self))], axis=0)
        return {"bbox_min": lo.tolist(), "bbox_max": hi.tolist()}

    def __getitem__(self, i: int) -> dict:
        x, mask, _ = self._load(i)
        if self.augment:
            g = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch * 7919 + int(i))
            x = rigid_augment(x, mask[0], g, self.aug_opts)
        return {"image": x, "mask": mask, "prompt": self.items[i][1], "index": int(i)}
