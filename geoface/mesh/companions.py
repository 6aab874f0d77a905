"""The files written beside a mesh file (:func:`geoface.mesh.io.save_mesh`): their names (an
OBJ's MTL and texture, a glTF's buffer, all named after the mesh), the refusal to replace
existing ones, and the atomic write of a file together with its companions."""

from __future__ import annotations

import os
from pathlib import Path


def companion_names(path: str | os.PathLike) -> list[Path]:
    """The files that belong to a mesh file and are written with it, all named after the mesh:
    for OBJ the MTL, the texture and the normal map (``head.obj`` → ``head.mtl``,
    ``head_texture.png``, ``head_normal.png``); for glTF its one buffer (``head.bin``); none
    for other formats."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".gltf":
        return [path.with_suffix(".bin")]
    if ext != ".obj":
        return []
    return [path.with_suffix(".mtl"), path.with_name(f"{path.stem}_texture.png"), path.with_name(f"{path.stem}_normal.png")]


def refuse_existing(paths, overwrite: bool, error) -> None:
    if overwrite:
        return
    for p in paths:
        if Path(p).exists():
            raise error(f"{p} exists; pass --force to replace it")


def without_maps(mtl) -> bytes:
    """An MTL without its image references (``map_*`` lines)."""
    text = mtl.decode("utf-8") if isinstance(mtl, bytes) else mtl
    return "".join(ln for ln in text.splitlines(True) if not ln.lstrip().lower().startswith("map_")).encode("utf-8")


def name_companions(path: Path, files: dict) -> dict:
    """trimesh names textures after materials (``material_0.png``): rename them after the
    mesh and point the MTL at the new names."""
    images = [k for k in files if not k.endswith(".mtl")]
    ren = {}
    for i, k in enumerate(images):
        ext = Path(k).suffix or ".png"
        ren[k] = f"{path.stem}_texture{ext}" if len(images) == 1 else f"{path.stem}_texture{i}{ext}"
    out = {}
    for k, data in files.items():
        if k.endswith(".mtl"):
            text = data.decode("utf-8") if isinstance(data, bytes) else data
            for old, new in ren.items():
                text = text.replace(f" {old}", f" {new}")
            out[k] = text.encode("utf-8")
        else:
            out[ren[k]] = data
    return out


class atomic_group:
    """Write a main file and its side files to temporaries, then rename them all (with the
    user's umask)."""

    def __init__(self, main: Path, side: dict):
        self.main = main
        self.side = {name: main.parent / name for name in side}

    def __enter__(self):
        import tempfile

        from .._io import temp_prefix, clean_stale_temporaries

        self.main.parent.mkdir(parents=True, exist_ok=True)
        self.tmps = {}
        for key, target in [("__main__", self.main), *self.side.items()]:
            clean_stale_temporaries(target)
            fd, tmp = tempfile.mkstemp(prefix=temp_prefix(target), suffix=".tmp", dir=target.parent)
            os.close(fd)
            self.tmps[key] = Path(tmp)
        return self.tmps["__main__"], {k: v for k, v in self.tmps.items() if k != "__main__"}

    def __exit__(self, exc_type, exc, tb):
        from .._io import default_mode

        if exc_type is None:
            mode = default_mode()
            for tmp in self.tmps.values():
                os.chmod(tmp, mode)
            for name, target in self.side.items():
                os.replace(self.tmps[name], target)
            os.replace(self.tmps["__main__"], self.main)
        else:
            for tmp in self.tmps.values():
                tmp.unlink(missing_ok=True)
        return False
