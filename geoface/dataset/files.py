"""The files a dataset build (:mod:`geoface.dataset`) reads: the meshes of the input folder,
their labels, and the manifest of the items built so far (``OUT_DIR/manifest.jsonl``, the last
line of an item wins)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import GeofaceError


MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
MANIFEST = "manifest.jsonl"


def find_meshes(in_dir: str | os.PathLike) -> list[Path]:
    """The mesh files directly inside ``in_dir`` (by suffix), sorted by name."""
    d = Path(in_dir)
    if not d.is_dir():
        raise GeofaceError(f"input folder not found: {d}")
    files = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
    if not files:
        raise GeofaceError(f"no mesh files ({', '.join(MESH_SUFFIXES)}) in {d}")
    stems: dict = {}
    for p in files:
        if p.stem in stems:
            raise GeofaceError(f"two meshes share the name {p.stem!r} ({stems[p.stem].name}, {p.name}); item folders are named by stem")
        stems[p.stem] = p
    return files


def load_labels(path: str | os.PathLike) -> dict:
    """Labels per mesh stem from ``.jsonl`` (one object per line with ``name`` or ``mesh``,
    e.g. ``{"name": "head_000", "prompt": "a smiling female", ...}``) or ``.json`` (an object
    mapping stem → labels, or a list of such lines)."""
    p = Path(path)
    if not p.is_file():
        raise GeofaceError(f"labels file not found: {p}")
    try:
        text = p.read_text()
        rows = [json.loads(line) for line in text.splitlines() if line.strip()] if p.suffix == ".jsonl" else json.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise GeofaceError(f"cannot read the labels file {p}: {e}") from None
    if isinstance(rows, dict):
        return {str(k): dict(v) for k, v in rows.items()}
    out = {}
    for i, r in enumerate(rows):
        key = r.get("name", r.get("mesh")) if isinstance(r, dict) else None
        if key is None:
            raise GeofaceError(f"labels file {p}: entry {i + 1} has no 'name' (the mesh's file stem)")
        out[Path(str(key)).stem] = dict(r)
    return out


def read_manifest(out_dir: str | os.PathLike) -> dict:
    """The last manifest line of every item, keyed by item name (``stem/aug{k}``)."""
    p = Path(out_dir) / MANIFEST
    last: dict = {}
    if p.is_file():
        try:
            text = p.read_bytes().decode("utf-8")
        except UnicodeDecodeError:
            raise GeofaceError(f"{p} is not a text file (not UTF-8); move it away or build into another folder") from None
        for line in text.splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut short by a killed run
            if isinstance(row, dict) and isinstance(row.get("item"), str):
                last[row["item"]] = row
    return last
