"""Where the ICT-FaceKit model (:mod:`geoface.synth.ict`) comes from, and packing it.

Where the model comes from: the packed ``ict_facekit.npz`` shipped with geoface (MIT licence
beside it), a path you give (a packed ``.npz``, or a clone of the public ICT-FaceKit
repository: its ``FaceXModel/`` OBJ files are read directly), or ``$GEOFACE_ICT_FACEKIT``.
``geoface synth pack-ict CLONE -o model.npz`` packs a clone into one file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import GeofaceError


_ENV = "GEOFACE_ICT_FACEKIT"
_NAME = "ict_facekit.npz"
_PACKAGED = Path(__file__).resolve().parent / "data" / _NAME


def _candidates() -> list[Path]:
    repo = Path(__file__).resolve().parents[2]
    out = []
    if os.environ.get(_ENV):
        out.append(Path(os.environ[_ENV]))
    out += [_PACKAGED, repo.parent / "shared" / "data" / "ict_facekit" / _NAME, repo / "data" / "ict_facekit" / _NAME]
    return out


def find_model(path: str | os.PathLike | None = None, *, required: bool = True) -> Path | None:
    """The model: ``path`` (a packed ``.npz``, a folder holding ``ict_facekit.npz``, or an
    ICT-FaceKit clone or its ``FaceXModel`` folder), else ``$GEOFACE_ICT_FACEKIT``, else the
    copy shipped with geoface.  Raises :class:`GeofaceError` naming the places tried when none
    exists (or returns None with ``required=False``)."""
    tried = []
    for p in ([Path(path)] if path is not None else _candidates()):
        if p.is_dir():
            if obj_folder(p) is not None:
                return p
            p = p / _NAME
        tried.append(str(p))
        if p.is_file():
            return p
    if required:
        raise GeofaceError(f"the ICT-FaceKit model was not found (tried {', '.join(tried)}); pass its path "
                           f"(a packed .npz or an ICT-FaceKit clone) or set {_ENV}")
    return None


def obj_folder(p: Path) -> Path | None:
    for d in (p / "FaceXModel", p):
        if (d / "generic_neutral_mesh.obj").is_file():
            return d
    return None


# ----------------------------------------------------------------------------- OBJ folder
def read_obj_polygons(path: str | os.PathLike, *, positions_only: bool = False):
    """Read an OBJ keeping its vertex order and polygons: ``(V (n, 3), P (m, 4), UV (t, 2), PUV (m, 4))``
    with triangles padded by -1 (``positions_only``: ``V`` alone).  Polygons of more than four
    corners are refused: the ICT-FaceKit meshes are quads and triangles."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as e:
        raise GeofaceError(f"cannot read {path}: {e}") from None
    vs, vts, fs = [], [], []
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("v "):
            vs.append(line[2:])
        elif positions_only:
            continue
        elif line.startswith("vt "):
            vts.append(line[3:])
        elif line.startswith("f "):
            corners = line[2:].split()
            if not 3 <= len(corners) <= 4:
                raise GeofaceError(f"{path}:{n}: a face of {len(corners)} corners (3 or 4 expected)")
            fs.append(corners)
    try:
        V = np.array([s.split()[:3] for s in vs], dtype=np.float64).reshape(-1, 3)
    except ValueError as e:
        raise GeofaceError(f"{path}: a vertex line is not three numbers ({e})") from None
    if len(V) == 0 or not np.isfinite(V).all():
        raise GeofaceError(f"{path}: no vertices, or non-finite coordinates")
    if positions_only:
        return V
    UV = np.array([s.split()[:2] for s in vts], dtype=np.float64).reshape(-1, 2) if vts else np.zeros((0, 2))
    P = np.full((len(fs), 4), -1, np.int64)
    PUV = np.full((len(fs), 4), -1, np.int64)
    try:
        for i, corners in enumerate(fs):
            for j, c in enumerate(corners):
                parts = c.split("/")
                P[i, j] = int(parts[0]) - 1
                if len(parts) > 1 and parts[1]:
                    PUV[i, j] = int(parts[1]) - 1
    except ValueError as e:
        raise GeofaceError(f"{path}: a face index is not an integer ({e})") from None
    if (P[:, :3] < 0).any() or P.max() >= len(V) or (len(UV) and PUV.max() >= len(UV)):
        raise GeofaceError(f"{path}: face indices out of range (OBJ indices start at 1)")
    if not len(UV):
        PUV[:] = -1
    return V, P, UV, PUV


def pack_from_folder(folder: Path, quiet: bool = True) -> dict:
    """The arrays of a packed model from an ICT-FaceKit ``FaceXModel`` folder."""
    from ..progress import progress

    V, P, UV, PUV = read_obj_polygons(folder / "generic_neutral_mesh.obj")
    idx = folder / "vertex_indices.json"
    try:
        info = json.loads(idx.read_text(encoding="utf-8")) if idx.is_file() else {}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise GeofaceError(f"cannot read {idx}: {e}") from None
    ids = sorted(p for p in folder.glob("identity[0-9][0-9][0-9].obj"))
    names = info.get("expressions")
    if names is None:  # every OBJ that is neither the neutral mesh nor an identity
        names = sorted(p.stem for p in folder.glob("*.obj") if p.stem != "generic_neutral_mesh" and not p.stem.startswith("identity"))
    missing = [n for n in names if not (folder / f"{n}.obj").is_file()]
    if missing:
        raise GeofaceError(f"{folder}: expression OBJs listed in vertex_indices.json are missing: {', '.join(missing[:5])}")
    lm = info.get("idx_to_landmark_verts")
    if lm is None and (folder.parent / "landmarks.json").is_file():
        lm = json.loads((folder.parent / "landmarks.json").read_text())["multi_pie_68"]

    def offsets(paths, what):
        out = np.zeros((len(paths), len(V), 3), np.float16)
        for k, p in enumerate(progress(paths, f"reading {what}", quiet=quiet)):
            T = read_obj_polygons(p, positions_only=True)
            if T.shape != V.shape:
                raise GeofaceError(f"{p}: {len(T)} vertices where the neutral mesh has {len(V)}")
            out[k] = (T - V).astype(np.float16)
        return out

    arrays = dict(neutral=V.astype(np.float32), faces=P.astype(np.int32), uv=UV.astype(np.float32),
                  face_uv=PUV.astype(np.int32), identity_modes=offsets(ids, "identities"),
                  identity_names=np.array([p.stem for p in ids]), expression_modes=offsets([folder / f"{n}.obj" for n in names], "expressions"),
                  expression_names=np.array(list(names)))
    if lm is not None:
        arrays["landmarks"] = np.asarray(lm, np.int64)
    return arrays


def pack_ict(src: str | os.PathLike, out: str | os.PathLike, *, overwrite: bool = False, quiet: bool = True) -> Path:
    """Pack an ICT-FaceKit clone (or its ``FaceXModel`` folder) into one ``.npz`` in the layout
    geoface reads (float16 modes, no pickle), atomically."""
    from .._io import atomic_path

    folder = obj_folder(Path(src))
    if folder is None:
        raise GeofaceError(f"{src} is not an ICT-FaceKit clone (no FaceXModel/generic_neutral_mesh.obj)")
    arrays = pack_from_folder(folder, quiet=quiet)
    out = Path(out)
    if out.exists() and not overwrite:
        raise GeofaceError(f"{out} exists; pass --force to replace it")
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return out
