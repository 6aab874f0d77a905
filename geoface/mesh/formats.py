"""Reading and writing details of mesh file formats that trimesh gets wrong or leaves to us:
OBJ relative indices, OFF vertex colours, glTF side files named after their mesh, the files
a mesh file refers to (:mod:`geoface.mesh.io` uses these)."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from ..errors import MeshFormatError, PointCloudError

__all__ = ["referenced_files", "absolute_obj_indices", "read_off", "gltf_one_buffer"]


def referenced_files(path: str | os.PathLike, *, limit: int = 1000) -> list[Path]:
    """The files a mesh file refers to (they belong to the input and are never outputs): an
    OBJ's material libraries and the images those name (``map_Kd``, ``bump``, ...), a glTF's
    buffers and images with a relative ``uri``.  Only files that exist; unreadable or odd
    references are skipped (reading the mesh reports those)."""
    path = Path(path)
    ext = path.suffix.lower()
    folder = path.parent
    out: list[Path] = []

    def add(name: str, base: Path):
        name = name.strip().strip('"')
        if not name or "://" in name or name.startswith("data:") or len(out) >= limit:
            return
        q = base / name
        with contextlib.suppress(OSError, ValueError):
            if q.is_file() and q not in out:
                out.append(q)

    try:
        if ext == ".obj":
            with open(path, encoding="utf-8", errors="replace") as fh:
                libs = [ln.split(None, 1)[1] for ln in fh if ln.startswith("mtllib") and len(ln.split(None, 1)) == 2]
            for lib in libs:
                add(lib, folder)
            for mtl in list(out):
                base = mtl.parent
                for ln in mtl.read_text(encoding="utf-8", errors="replace").splitlines():
                    w = ln.split()
                    if w and (w[0].lower().startswith("map_") or w[0].lower() in ("bump", "disp", "decal", "refl", "norm")):
                        add(w[-1], base)
        elif ext == ".gltf" and path.stat().st_size < 64 << 20:
            import json

            d = json.loads(path.read_text(encoding="utf-8"))
            for key in ("buffers", "images"):
                for item in (d.get(key) or []) if isinstance(d, dict) else []:
                    if isinstance(item, dict) and isinstance(item.get("uri"), str):
                        add(item["uri"], folder)
    except (OSError, ValueError, UnicodeError):
        return out
    return out


def gltf_one_buffer(path: Path, data: dict) -> tuple[bytes, dict]:
    """trimesh's glTF export as one JSON and one buffer named after the mesh (``head.bin``):
    its ``gltf_buffer_N.bin`` names are shared by every glTF in a folder, so a second export
    beside the first would replace the first's geometry."""
    import json

    doc = json.loads(data["model.gltf"])
    buffers = doc.get("buffers") or []
    blob, offsets = bytearray(), []
    for b in buffers:
        offsets.append(len(blob))
        blob += data[b["uri"]]
        blob += b"\0" * (-len(blob) % 4)  # glTF alignment
    for view in doc.get("bufferViews") or []:
        k = view.get("buffer", 0)
        view["buffer"] = 0
        view["byteOffset"] = int(view.get("byteOffset", 0)) + offsets[k]
    if buffers:
        doc["buffers"] = [{"uri": path.with_suffix(".bin").name, "byteLength": len(blob)}]
    side = {path.with_suffix(".bin").name: bytes(blob)} if buffers else {}
    return json.dumps(doc).encode("utf-8"), side


_OBJ_KIND = {"v": "vertex", "vt": "texture coordinate", "vn": "normal"}


def absolute_obj_indices(text: str, name: str = "the OBJ") -> str | None:
    """``text`` with every negative (relative) OBJ index made absolute, or None when it has
    none.  In OBJ ``-1`` is the last vertex *defined so far*; trimesh reads it as the last of
    the file, which is wrong as soon as vertices follow a face.  An index that points before the
    first vertex (``-5`` after three) is a :class:`MeshFormatError` naming ``name`` and the line,
    not an index that wraps round to the end."""
    import re

    if not re.search(r"^[ \t]*[fl][ \t][^\n]*(?<=[ \t/])-\d", text, re.M):
        return None
    counts = {"v": 0, "vt": 0, "vn": 0}
    out = []
    for number, ln in enumerate(text.splitlines(), 1):
        w = ln.split()
        if w and w[0] in counts:
            counts[w[0]] += 1
        elif w and w[0] in ("f", "l") and "-" in ln:
            toks = []
            for tok in w[1:]:
                parts = tok.split("/")
                for k, key in enumerate(("v", "vt", "vn")[: len(parts)]):
                    if parts[k].startswith("-"):
                        try:
                            absolute = counts[key] + int(parts[k]) + 1
                        except ValueError:
                            continue  # not a number: trimesh reports it
                        if absolute < 1:
                            raise MeshFormatError(f"{name}, line {number}: index {parts[k]} points before the first "
                                                  f"{_OBJ_KIND[key]} ({counts[key]} defined so far)")
                        parts[k] = str(absolute)
                toks.append("/".join(parts))
            ln = " ".join([w[0], *toks])
        out.append(ln)
    return "\n".join(out) + "\n"


def read_off(path: Path) -> tuple:
    """An OFF file (``OFF``, ``COFF``, ``NOFF``, ``CNOFF``, ``STOFF`` headers), with its vertex
    colours (RGB or RGBA after the coordinates, 0-255 or 0-1) when every vertex has them;
    polygons are split into triangle fans.  Returns ``(V, F, colors or None)``."""
    try:
        raw = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise MeshFormatError(f"cannot read {path.name}: {exc}") from None
    lines = [ln.split("#", 1)[0].split() for ln in raw.splitlines()]
    lines = [w for w in lines if w]
    bad = MeshFormatError
    if not lines:
        raise bad(f"cannot read {path.name} as OFF: no header")
    head = lines[0]
    key = head[0].upper()
    if not key.endswith("OFF"):
        raise bad(f"cannot read {path.name} as OFF: the first word is {head[0][:20]!r}, not OFF")
    if "4" in key or head[0].startswith("n"):
        raise bad(f"{path.name}: {head[0]} (4D or n-dimensional OFF) is not a surface geoface reads")
    rest = head[1:]
    k = 1
    if len(rest) < 2:
        if k >= len(lines):
            raise bad(f"cannot read {path.name} as OFF: no vertex and face counts")
        rest = lines[k]
        k += 1
    try:
        nv, nf = int(rest[0]), int(rest[1])
    except (ValueError, IndexError):
        raise bad(f"cannot read {path.name} as OFF: bad counts {' '.join(rest)[:60]!r}") from None
    if nv < 0 or nf < 0 or k + nv + nf > len(lines):
        raise bad(f"{path.name}: the header promises {nv} vertices and {nf} faces; the file has {len(lines) - k} lines")
    try:
        vrows = lines[k: k + nv]
        V = np.array([[float(x) for x in r[:3]] for r in vrows], np.float64).reshape(-1, 3)
        ncol = {len(r) for r in vrows}
        normals = 3 if "N" in key.replace("OFF", "") else 0
        texcoord = 2 if "ST" in key else 0
        colors = None
        extra = min(ncol) - 3 - normals - texcoord if vrows else 0
        if extra >= 3 and ("C" in key or len(ncol) == 1):
            c0 = 3 + normals
            C = np.array([[float(x) for x in r[c0: c0 + min(extra, 4)]] for r in vrows], np.float64)
            scale = 255.0 if C.max(initial=0.0) > 1.0 else 1.0
            C = np.clip(C / scale, 0.0, 1.0)
            colors = np.column_stack([C, np.ones(len(C))]) if C.shape[1] == 3 else C
        tris = []
        for r in lines[k + nv: k + nv + nf]:
            n = int(r[0])
            idx = [int(x) for x in r[1: 1 + n]]
            if n < 3 or len(idx) != n:
                raise ValueError(f"a face of {n} corners: {' '.join(r)[:60]}")
            tris.extend([idx[0], idx[j], idx[j + 1]] for j in range(1, n - 1))
    except (ValueError, IndexError) as exc:
        raise bad(f"cannot read {path.name} as OFF: {exc}") from None
    F = np.array(tris, np.int64).reshape(-1, 3)
    if len(F) == 0:
        if len(V) == 0:
            raise bad(f"{path.name} has no vertices and no faces")
        raise PointCloudError(f"{path.name} is a point cloud ({len(V)} points, no triangles)")
    return V, F, colors
