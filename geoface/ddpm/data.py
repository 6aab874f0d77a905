"""Torch dataset over geometry-image folders (the dataset builder's output or any folder tree).

Each item is a dict:

* ``image``  ``[C, R, R]`` float32: the modalities (position, normal and, where every item has
  one, texture) stacked, 3 channels each, in about [-1, 1]; uncovered pixels are 0.
* ``mask``   ``[1, R, R]`` float32 coverage (1 = valid pixel).
* ``prompt`` str (``""`` when none is known).
* ``index``  int.

The items, their sources (a manifest or a folder tree) and the one position frame of the
whole dataset are :mod:`geoface.ddpm.data_items`; downsampling and the rigid augmentation
:mod:`geoface.ddpm.data_transforms`.

**Lazy**: items are read from disk when asked for; at most ``cache_mb`` of decoded items are
kept (float16, least recently used first), so memory stays bounded whatever the dataset size.
Normals and texture map ``[0, 1] → [-1, 1]``.

**Standardisation** (:class:`DataStats`, :func:`data_stats`): heads are alike, so what a
model must learn is how a head differs from the others, not where a head is.  The diffusion
model sees ``(x - mean) / std``: the dataset's mean image subtracted and each modality divided
by one standard deviation of what is left, so the part of the image that varies has unit
variance whatever the modality, and a denoising error costs ``std`` (a few hundredths) in the
data space rather than its full size.

:class:`ShardSampler` draws item indices for one process of a distributed run: its own shard
of the items and its own seed.
"""
from __future__ import annotations

import json
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from geoface.errors import GeofaceError

from .data_items import Item, Normalization, find_items
from .data_transforms import AugmentOptions, area_resize, rigid_augment, unit_normals

__all__ = ["GImageDataset", "AugmentOptions", "Normalization", "DataStats", "data_stats", "ShardSampler", "Item",
           "find_items", "area_resize", "rigid_augment", "unit_normals", "CHANNELS"]

CHANNELS = ("position", "normal", "texture")


@dataclass(frozen=True)
class DataStats:
    """``standardised = (x - mean) / std`` for stacked images ``x [C, R, R]``.

    ``mean`` ``[C, R, R]``: the dataset's mean image; ``std`` ``[C]``: one standard deviation
    per modality (the same for its three channels) of ``x - mean`` over items and pixels, or
    ``[C, R, R]``: one per modality and pixel (over items); ``bound``: the largest
    ``|standardised|`` seen (what sampling clips its x0 estimates to); ``support`` ``[R, R]``
    bool: the pixels every item covers (None when unknown).  Stored beside a checkpoint as
    ``data_stats.safetensors``."""

    mean: np.ndarray
    std: np.ndarray
    bound: float
    support: np.ndarray | None = None

    #: a modality that does not vary at all (one item, a constant channel) is divided by this
    MIN_STD = 1e-3

    def forward(self, x: torch.Tensor) -> torch.Tensor:   # [B, C, R, R] -> standardised
        m, s = self._tensors(x)
        return (x - m) / s

    def inverse(self, z: torch.Tensor) -> torch.Tensor:   # standardised -> [B, C, R, R]
        m, s = self._tensors(z)
        return z * s + m

    def _tensors(self, x: torch.Tensor):
        if tuple(x.shape[-3:]) != tuple(self.mean.shape):
            raise GeofaceError(f"images of shape {tuple(x.shape[-3:])} do not match the data statistics {tuple(self.mean.shape)}")
        m = torch.from_numpy(self.mean).to(device=x.device, dtype=x.dtype)
        s = torch.from_numpy(self.std).to(device=x.device, dtype=x.dtype)
        return m, (s[:, None, None] if s.ndim == 1 else s)

    def save(self, path: str | os.PathLike) -> None:
        from safetensors.torch import save_file
        save_file({"mean": torch.from_numpy(np.ascontiguousarray(self.mean, np.float32)),
                   "std": torch.from_numpy(np.ascontiguousarray(self.std, np.float32)),
                   "bound": torch.tensor([float(self.bound)], dtype=torch.float32),
                   **({"support": torch.from_numpy(np.ascontiguousarray(self.support, np.uint8))}
                      if self.support is not None else {})}, str(path))
        from .._io import default_mode

        os.chmod(path, default_mode())  # the user's umask (safetensors writes 0600)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "DataStats":
        from safetensors.torch import load_file
        try:
            t = load_file(str(path))
            mean, std, bound = t["mean"].numpy(), t["std"].numpy(), float(t["bound"][0])
            support = t["support"].numpy().astype(bool) if "support" in t else None
        except Exception as e:  # missing keys, truncated file
            raise GeofaceError(f"{path} is not a valid data statistics file ({type(e).__name__}: {e})") from None
        if (mean.ndim != 3 or std.shape not in ((mean.shape[0],), mean.shape)
                or (support is not None and support.shape != mean.shape[1:])
                or not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()
                        and np.isfinite(bound) and bound > 0)):
            raise GeofaceError(f"{path}: data statistics of the wrong shape or not finite")
        return cls(mean.astype(np.float32), std.astype(np.float32), bound, support)


def data_stats(ds: "GImageDataset", max_items: int = 1024, seed: int = 0, quiet: bool | None = True,
               per_pixel: bool = False, floor: float = 0.1) -> DataStats:
    """:class:`DataStats` of ``ds`` as training sees it (augmented when ``ds.augment``) over at
    most ``max_items`` items drawn without replacement: the mean image first, then the residual
    spread, in two passes over the same draws.

    ``per_pixel``: one spread per modality and pixel (over the items), at least ``floor`` times
    the modality's overall spread, instead of one per modality.  The support is the pixels
    every drawn item covers."""
    from geoface.progress import progress

    n = len(ds)
    idx = np.arange(n) if n <= max_items else np.sort(np.random.default_rng(seed).choice(n, max_items, replace=False))
    keys = [(int(i), int(k)) for k, i in enumerate(idx)]  # the draw number seeds the augmentation
    total, support = None, None
    for key in progress(keys, "data statistics (mean)", quiet=quiet):
        it = ds[key]
        x = it["image"].double().numpy()
        total = x.copy() if total is None else total + x
        m = it["mask"].numpy().reshape(x.shape[1:]) > 0.5
        support = m if support is None else support & m
    mean = total / len(keys)
    C = mean.shape[0]
    sq, peak = np.zeros_like(mean), np.zeros(C)
    for key in progress(keys, "data statistics (spread)", quiet=quiet):
        r = ds[key]["image"].double().numpy() - mean
        sq += r ** 2
        peak = np.maximum(peak, np.abs(r).max(axis=(1, 2)))
    R2 = mean.shape[1] * mean.shape[2]
    groups = sq.reshape(C // 3, 3, -1).sum(axis=(1, 2)) / (3 * len(keys) * R2)
    std = np.repeat(np.maximum(np.sqrt(groups), DataStats.MIN_STD), 3)
    if not per_pixel:
        bound = float((peak / std).max())
    else:  # the bound needs the final spread: a third pass
        pix = np.sqrt(sq.reshape(C // 3, 3, *mean.shape[1:]).sum(axis=1) / (3 * len(keys)))  # [M, R, R]
        std = np.repeat(np.maximum(pix, floor * std[::3, None, None]), 3, axis=0)
        bound = max(float(np.abs((ds[key]["image"].double().numpy() - mean) / std).max()) for key in keys)
    return DataStats(mean.astype(np.float32), std.astype(np.float32), max(bound, 1.0), support)


class GImageDataset(torch.utils.data.Dataset):
    """Geometry images as ``[C, R, R]`` tensors + mask + prompt (see module doc).

    Parameters
    ----------
    data_dir : dataset folder
    res : training resolution (divides the image resolution; None = as stored)
    augment, seed, augment_options : rigid augmentation (seeded per draw)
    normalization : positions' :class:`Normalization` (default: computed from this dataset's
        boxes; pass a run's own to decode or to train on a second dataset in the same frame)
    modalities : the modalities to stack (default: position and normal, plus texture when
        every item has one)
    cache_mb : decoded items kept in memory, at most this many megabytes (0 = none)
    """

    def __init__(self, data_dir: str | os.PathLike, res: int | None = None, augment: bool = False,
                 seed: int = 0, augment_options: AugmentOptions = AugmentOptions(),
                 normalization: Normalization | None = None, modalities: tuple | None = None, cache_mb: float = 256.0):
        self.root = Path(data_dir)
        self.items = find_items(data_dir)
        self.res, self.augment, self.seed, self.aug_opts = res, augment, int(seed), augment_options
        self.epoch = 0
        self._cache: OrderedDict = OrderedDict()
        self._cache_bytes, self._cache_limit = 0, int(max(0.0, float(cache_mb)) * 2**20)
        self.normalization = normalization or self._dataset_normalization()
        self.modalities = tuple(modalities) if modalities is not None else self._common_modalities()
        bad = [m for m in self.modalities if m not in CHANNELS]
        if bad or self.modalities[:2] != ("position", "normal"):
            raise GeofaceError(f"modalities must start with position, normal (then texture); got {self.modalities}")

    def __len__(self) -> int:
        return len(self.items)

    @property
    def channels(self) -> int:
        return 3 * len(self.modalities)

    @property
    def prompts(self) -> list[str]:
        return [it.prompt for it in self.items]

    def _meta(self, i: int) -> dict:
        p = self.items[i].folder / "meta.json"
        try:
            m = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise GeofaceError(f"cannot read {p}: {e}") from None
        if not isinstance(m, dict):
            raise GeofaceError(f"{p} must hold a JSON object")
        return m

    def _box(self, i: int):
        if self.items[i].bbox is not None:
            return self.items[i].bbox
        m = self._meta(i)
        try:
            return tuple(float(x) for x in m["bbox_min"]), tuple(float(x) for x in m["bbox_max"])
        except (KeyError, TypeError, ValueError):
            raise GeofaceError(f"{self.items[i].folder / 'meta.json'} has no valid bbox_min / bbox_max") from None

    def _dataset_normalization(self) -> Normalization:
        boxes = [self._box(i) for i in range(len(self))]
        return Normalization.from_boxes([b[0] for b in boxes], [b[1] for b in boxes])

    def _common_modalities(self) -> tuple:
        # the manifest does not list channels: look at a few items (an item that lacks what
        # these have fails when it is read, naming itself)
        probe = sorted({0, len(self) // 2, len(self) - 1})
        return ("position", "normal", "texture") if all(self._has_texture(i) for i in probe) else ("position", "normal")

    def _has_texture(self, i: int) -> bool:
        from geoface.gimage.image import MODALITIES

        ch = self._meta(i).get("channels", [])
        return isinstance(ch, list) and all(c in ch for c in MODALITIES["texture"])

    def _decode(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        from geoface.gimage import load_gimage

        gi = load_gimage(self.items[i].folder)
        try:
            parts = [gi.modality(m) for m in self.modalities]
        except GeofaceError as e:
            raise GeofaceError(f"{self.items[i].folder}: {e} (the dataset's other items have {', '.join(self.modalities)})") from None
        img = np.concatenate(parts, axis=0).astype(np.float32)
        mask = np.asarray(gi.mask, bool)
        # positions to mesh units (this item's box), then to the dataset frame
        lo, hi = (np.asarray(b, np.float64) for b in (gi.meta["bbox_min"], gi.meta["bbox_max"]))
        nz = self.normalization
        scale = ((hi - lo) / (2 * nz.scale))[:, None, None]
        off = ((lo - np.asarray(nz.center)) / nz.scale)[:, None, None]
        img[0:3] = (img[0:3] * 2 * scale + off).astype(np.float32)
        img[3:] = img[3:] * 2.0 - 1.0
        if self.res is not None and self.res != img.shape[-1]:
            full = img
            img, mask = area_resize(img, mask, int(self.res))
            if "normal" in self.modalities:  # a block's mean normal is shorter than 1 where it bends
                k = 3 * list(self.modalities).index("normal")
                img[k:k + 3] = unit_normals(img[k:k + 3], full[k:k + 3], mask)
        return img * mask[None], mask

    def _load(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        hit = self._cache.get(i)
        if hit is not None:
            self._cache.move_to_end(i)
            x, m = hit
            return torch.from_numpy(x.astype(np.float32)), torch.from_numpy(m.astype(np.float32))[None]
        img, mask = self._decode(i)
        if self._cache_limit:
            x16, m8 = img.astype(np.float16), mask.astype(np.uint8)
            size = x16.nbytes + m8.nbytes
            if size <= self._cache_limit:
                self._cache[i] = (x16, m8)
                self._cache_bytes += size
                while self._cache_bytes > self._cache_limit:
                    _, (a, b) = self._cache.popitem(last=False)
                    self._cache_bytes -= a.nbytes + b.nbytes
            img = x16.astype(np.float32)  # the same values whether or not the item came from the cache
        return torch.from_numpy(img), torch.from_numpy(mask.astype(np.float32))[None]

    def meta(self, i: int) -> dict:
        return self._meta(i)

    def bbox_stats(self) -> dict:
        """The cube of the dataset normalisation as ``bbox_min``/``bbox_max`` (what decodes a
        sample in [-1, 1] back to mesh units), and the normalisation itself."""
        lo, hi = self.normalization.box()
        return {"bbox_min": lo, "bbox_max": hi, "normalization": self.normalization.to_dict(),
                "modalities": list(self.modalities)}

    def __getitem__(self, key) -> dict:
        """``key``: an index, or ``(index, draw)`` from :class:`ShardSampler` (the draw seeds
        the augmentation, so every draw of an item is augmented differently and reproducibly)."""
        i, draw = (int(key[0]), int(key[1])) if isinstance(key, (tuple, list)) else (int(key), None)
        x, mask = self._load(i)
        if self.augment:
            s = self.seed * 1_000_003 + (self.epoch * 7919 + i if draw is None else draw * 2_654_435_761 + i)
            g = torch.Generator().manual_seed(s % (2**63))
            x = rigid_augment(x, mask[0], g, self.aug_opts)
        return {"image": x, "mask": mask, "prompt": self.items[i].prompt, "index": i}


class ShardSampler(torch.utils.data.Sampler):
    """Endless ``(index, draw)`` pairs for process ``rank`` of ``world``: indices drawn
    uniformly (with replacement) from the items ``rank, rank + world, ...``, from a generator
    seeded by ``(seed, rank)``; ``draw`` counts up from ``start`` (a resumed run continues the
    stream).  Every process thus sees its own items in its own order."""

    def __init__(self, n: int, *, rank: int = 0, world: int = 1, seed: int = 0, start: int = 0):
        if not 0 <= rank < world:
            raise GeofaceError(f"rank must be in 0..{world - 1}; got {rank}")
        self.shard = np.arange(rank, n, world)
        if len(self.shard) == 0:
            raise GeofaceError(f"{n} items cannot be shared among {world} processes")
        self.rank, self.world, self.seed, self.start = rank, world, int(seed), int(start)

    def __iter__(self):
        rng = np.random.default_rng([self.seed, self.rank, self.start])
        draw = self.start * self.world + self.rank
        while True:
            for i in rng.integers(0, len(self.shard), 1024):
                yield int(self.shard[i]), draw
                draw += self.world

    def __len__(self) -> int:  # one pass over the shard (the stream itself is endless)
        return len(self.shard)
