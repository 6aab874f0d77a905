"""The items of a geometry-image dataset (:mod:`geoface.ddpm.data`) and the one frame their
positions are put in.

Sources: ``DATA_DIR/manifest.jsonl`` (see :mod:`geoface.dataset`: rows with ``status == "ok"``,
item folder ``DATA_DIR/<item>``, optional ``prompt``; the last row of an item wins) or, with no
manifest, every folder below ``DATA_DIR`` holding a ``meta.json`` (prompt from
``meta["prompt"]`` if present).

**One position normalisation for the whole dataset** (:class:`Normalization`): positions are
decoded to mesh units from each item's box and mapped by one centre and one scale — the
centre and 1.05 × the largest half-extent of the union of the items' boxes — so head proportions and
sizes survive (a per-item box would stretch every head to the same cube).  The boxes come from
the manifest rows (``bbox``, written by ``geoface dataset build``) or, for older datasets and
plain folder trees, from each item's ``meta.json``.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError


@dataclass(frozen=True)
class Item:
    folder: Path
    prompt: str
    bbox: tuple | None = None  # ((3,), (3,)) mesh-unit box of the position image, when the manifest has it


@dataclass(frozen=True)
class Normalization:
    """``normalised = (p - center) / scale`` for positions ``p`` in mesh units."""

    center: tuple
    scale: float

    #: the union box's largest half-extent is mapped to 1 / MARGIN: the data lie in about
    #: [-0.95, 0.95], which leaves samples room before the [-1, 1] clamp
    MARGIN = 1.05

    @classmethod
    def from_boxes(cls, lo: np.ndarray, hi: np.ndarray) -> "Normalization":
        lo, hi = np.min(np.asarray(lo, np.float64), axis=0), np.max(np.asarray(hi, np.float64), axis=0)
        scale = float(np.max(hi - lo) / 2) * cls.MARGIN
        if not np.isfinite(scale) or scale <= 0:
            raise GeofaceError("the dataset's position boxes are empty or not finite")
        return cls(tuple(float(x) for x in (lo + hi) / 2), scale)

    def to_dict(self) -> dict:
        return {"center": list(self.center), "scale": self.scale}

    @classmethod
    def from_dict(cls, d: dict) -> "Normalization":
        try:
            c = [float(x) for x in d["center"]]
            s = float(d["scale"])
        except (KeyError, TypeError, ValueError):
            raise GeofaceError(f"a normalisation needs 'center' (3 numbers) and 'scale'; got {d!r}") from None
        if len(c) != 3 or not np.isfinite(c).all() or not (np.isfinite(s) and s > 0):
            raise GeofaceError(f"bad normalisation {d!r}")
        return cls(tuple(c), s)

    def box(self) -> tuple[list, list]:
        """The cube ``center ± scale`` (where normalised -1 and 1 land), as bbox_min / bbox_max."""
        c = np.asarray(self.center)
        return (c - self.scale).tolist(), (c + self.scale).tolist()


def _bbox_of(row: dict):
    b = row.get("bbox")
    if isinstance(b, dict) and isinstance(b.get("min"), list) and isinstance(b.get("max"), list):
        lo, hi = np.asarray(b["min"], np.float64), np.asarray(b["max"], np.float64)
        if lo.shape == hi.shape == (3,) and np.isfinite(lo).all() and np.isfinite(hi).all():
            return tuple(lo.tolist()), tuple(hi.tolist())
    return None


def find_items(data_dir: str | os.PathLike) -> list[Item]:
    """The dataset's items (folder, prompt, box when the manifest has it) in a stable (sorted) order."""
    root = Path(data_dir)
    if not root.is_dir():
        raise GeofaceError(f"data folder not found: {root}")
    man = root / "manifest.jsonl"
    items: list[Item] = []
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
                items.append(Item(folder, str(row.get("prompt") or ""), _bbox_of(row)))
    else:
        for meta in sorted(root.rglob("meta.json")):
            try:
                m = json.loads(meta.read_text(encoding="utf-8"))
                prompt = str(m.get("prompt") or "") if isinstance(m, dict) else ""
            except (OSError, json.JSONDecodeError, UnicodeDecodeError):
                prompt = ""
            items.append(Item(meta.parent, prompt))
    if not items:
        raise GeofaceError(f"no geometry images found in {root} (need manifest.jsonl rows with status 'ok' "
                           "or folders with meta.json)")
    return items
