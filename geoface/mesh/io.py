"""Load and save meshes (OBJ, PLY, OFF, STL, GLB/GLTF) through trimesh, keeping colours and UVs.

Geometry and attributes travel separately, as in libigl's ``readOBJ``:

* ``V, F`` — the *geometric* mesh.  On load, vertices with bit-identical positions are
  welded (files split vertices at UV seams, STL stores a triangle soup); tolerance-based
  merging is a repair step, not a load step.
* ``UV, FUV`` — texture coordinates per face corner (``UV[FUV[f, k]]`` is the UV of
  corner ``k`` of face ``f``), so UV seams survive welding.
* ``colors`` — per-vertex RGBA in ``[0, 1]``; ``texture`` — the texture image (uint8).

An OBJ of ``v`` and triangle ``f`` lines only (most scans) is parsed with NumPy, several times
faster and with the same result; every other file goes through trimesh.

The :class:`Mesh` that holds them is :mod:`geoface.mesh.mesh_data`; the files written beside a
mesh file (MTL, texture, glTF buffer) are :mod:`geoface.mesh.companions`.

>>> m = load_mesh("head.obj")                        # doctest: +SKIP
>>> save_mesh("copy.ply", m)                           # doctest: +SKIP
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .._io import atomic_path
from ..errors import GeofaceWarning, InvalidMeshError, MeshFormatError, PointCloudError
from .companions import atomic_group, companion_names, name_companions, refuse_existing, without_maps
from . import objtext
from .core import check_mesh
from .formats import referenced_files  # noqa: F401  (re-exported: the files a mesh file refers to)
from .mesh_data import Mesh, first_corner_uv, mesh_with  # noqa: F401  (re-exported: the mesh a file loads into)

#: file extensions geoface reads and writes
FORMATS = ("obj", "ply", "off", "stl", "glb", "gltf")


def format_of(path) -> str:
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise MeshFormatError(f"unsupported mesh format '.{ext}' for {path}; use one of: {', '.join(FORMATS)}")
    return ext


def load_mesh(path: str | os.PathLike, *, weld: bool = True) -> Mesh:
    """Read a mesh file into a :class:`Mesh`.

    Parameters
    ----------
    path : file path with extension obj, ply, off, stl, glb or gltf
    weld : merge vertices with bit-identical positions (default True; see module docs)

    Raises
    ------
    MeshFormatError
        Missing, empty, unreadable or corrupt file; a file without triangles (a point cloud).
    InvalidMeshError
        NaN coordinates or face indices out of range.
    """
    path = Path(path)
    if path.is_dir():
        raise MeshFormatError(f"{path} is a folder, not a mesh file (obj, ply, off, stl, glb, gltf)")
    ext = format_of(path)
    if not path.is_file():
        raise MeshFormatError(f"no such file: {path}")
    if path.stat().st_size == 0:
        raise MeshFormatError(f"file is empty: {path}")
    if ext == "off":
        from .formats import read_off

        return _checked_mesh(*read_off(path), weld)
    source = str(path)
    if ext == "obj":
        try:
            text = path.read_text(errors="replace")
        except OSError as exc:
            raise MeshFormatError(f"cannot read {path.name}: {exc}") from None
        plain = _plain_obj(text)
        if plain is not None:  # v / f lines only: parsed here, ~10x faster than trimesh
            return _checked_mesh(*plain, None, weld)
        _check_obj_indices(path, text)
        from .formats import absolute_obj_indices

        fixed = absolute_obj_indices(text, path.name)
        if fixed is not None:  # negative (relative) indices: trimesh counts them from the end of the file
            import io

            source = io.BytesIO(fixed.encode("utf-8"))
    import trimesh

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if isinstance(source, str):
                loaded = trimesh.load(source, file_type=ext, process=False)
            else:
                loaded = trimesh.load(source, file_type=ext, process=False,
                                      resolver=trimesh.resolvers.FilePathResolver(str(path)))
    except Exception as exc:  # trimesh raises many kinds for corrupt input
        raise MeshFormatError(f"cannot read {path.name} as {ext.upper()}: {type(exc).__name__}: {exc}") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)] if loaded.geometry else []
        if not geoms:
            raise MeshFormatError(f"{path.name} contains no triangle mesh")
        if len(geoms) > 1:
            loaded = trimesh.util.concatenate(geoms)
        else:
            loaded = geoms[0]
    if not isinstance(loaded, trimesh.Trimesh):
        if isinstance(loaded, trimesh.PointCloud):
            raise PointCloudError(f"{path.name} is a point cloud ({len(loaded.vertices)} points, no triangles)")
        raise MeshFormatError(f"{path.name} contains no triangles ({type(loaded).__name__}: a path?)")
    V = np.asarray(loaded.vertices, np.float64)
    F = np.asarray(loaded.faces, np.int64).reshape(-1, 3) if len(loaded.faces) else np.zeros((0, 3), np.int64)
    if len(F) == 0:
        raise PointCloudError(f"{path.name} is a point cloud ({len(V)} points, no triangles)")
    V, F = check_mesh(V, F)
    UV = FUV = colors = texture = None
    vis = loaded.visual
    kind = getattr(vis, "kind", None)
    if kind == "texture" and getattr(vis, "uv", None) is not None and len(vis.uv) == len(V):
        UV = np.asarray(vis.uv, np.float64)
        FUV = F.copy()
        texture = _material_image(vis.material)
    elif kind == "vertex":
        colors = np.asarray(vis.vertex_colors, np.float64) / 255.0
    elif kind == "face":
        warnings.warn(f"{path.name}: per-face colours are not kept (geoface stores vertex colours)", GeofaceWarning, stacklevel=2)
    if weld:
        V, F, first = _weld_exact(V, F)
        if colors is not None:
            colors = colors[first]
    return Mesh(V, F, UV=UV, FUV=FUV, colors=colors, texture=texture)


def _checked_mesh(V, F, colors, weld: bool) -> Mesh:
    """The :class:`Mesh` of a reader's arrays: checked, and welded when asked."""
    V, F = check_mesh(V, F)
    if weld:
        V, F, first = _weld_exact(V, F)
        if colors is not None:
            colors = colors[first]
    return Mesh(V, F, colors=colors)


def _weld_exact(V: np.ndarray, F: np.ndarray):
    """Merge vertices with bit-identical positions, keeping first-seen order.

    Returns ``(V, F, first)`` with ``first[i]`` the input index of output vertex ``i``.
    """
    order = np.lexsort((V[:, 2], V[:, 1], V[:, 0]))
    Vs = V[order]
    new_group = np.r_[True, (Vs[1:] != Vs[:-1]).any(1)]
    gid_sorted = np.cumsum(new_group) - 1
    gid = np.empty(len(V), np.int64)
    gid[order] = gid_sorted
    ng = int(gid_sorted[-1]) + 1
    if ng == len(V):
        return V, F, np.arange(len(V))
    first = np.full(ng, len(V))
    np.minimum.at(first, gid, np.arange(len(V)))
    rank_order = np.argsort(first)  # groups in first-seen order
    rank = np.empty(ng, np.int64)
    rank[rank_order] = np.arange(ng)
    first = first[rank_order]
    return V[first], rank[gid][F], first


def _material_image(material) -> np.ndarray | None:
    img = getattr(material, "image", None)
    if img is None:
        img = getattr(material, "baseColorTexture", None)
    if img is None:
        return None
    arr = np.asarray(img)
    if arr.shape[:2] == (2, 2) and (arr == arr.reshape(4, -1)[0]).all():
        return None  # trimesh's placeholder for a missing material image
    return arr.astype(np.uint8) if arr.dtype != np.uint8 else arr


def _split_at_seams(F: np.ndarray, FUV: np.ndarray, n_uv: int):
    """One output vertex per distinct (vertex, UV) corner pair, in the order of the pairs:
    (vertex index, UV index, faces over the new vertices).  The pairs are one int64 key each,
    so the sort is a plain 1-D one (``np.unique(axis=0)`` sorts structured rows, ~15x slower)."""
    if FUV.shape == F.shape and np.array_equal(F, FUV):  # one UV per vertex (a geometry image's mesh): no seams
        used = np.zeros(max(int(n_uv), int(F.max(initial=-1)) + 1), bool)
        used[F.ravel()] = True
        vi = np.flatnonzero(used)
        rank = np.cumsum(used) - 1
        return vi, vi.copy(), rank[F].astype(np.int64)
    key = F.astype(np.int64).ravel() * max(int(n_uv), 1) + FUV.astype(np.int64).ravel()
    uniq, inv = np.unique(key, return_inverse=True)
    vi, ti = np.divmod(uniq, max(int(n_uv), 1))
    return vi, ti, inv.reshape(-1, 3)


def _fast_obj(tm, mtl: str, digits: int):
    """OBJ text of a mesh without vertex colours by :mod:`.objtext`, and its companion files
    (MTL, texture) as trimesh writes them, taken from a one-triangle stand-in with the same
    material."""
    import trimesh
    from trimesh.exchange.obj import export_obj

    uv = getattr(tm.visual, "uv", None)
    head = "# geoface\n"
    files = {}
    if uv is not None:
        stand_in = trimesh.Trimesh(tm.vertices[:3], [[0, 1, 2]], process=False,
                                   visual=trimesh.visual.TextureVisuals(uv=uv[:3], material=tm.visual.material))
        result = export_obj(stand_in, include_texture=True, include_normals=False, mtl_name=mtl, return_texture=True)
        stand_text, files = result if isinstance(result, tuple) else (result, {})
        head += "".join(ln + "\n" for ln in stand_text.splitlines() if ln.startswith(("mtllib", "usemtl")))
    body = objtext.obj_body(np.asarray(tm.vertices), np.asarray(tm.faces), None if uv is None else np.asarray(uv), digits)
    return head.encode() + body, files


def _to_trimesh(mesh: Mesh, ext: str):
    """Build a trimesh object, splitting vertices at UV seams when UVs are present."""
    import trimesh

    dropped = []
    if mesh.UV is not None and ext in ("obj", "ply", "glb", "gltf"):
        vi, ti, F = _split_at_seams(mesh.F, mesh.FUV, len(mesh.UV))
        V = mesh.V[vi]
        uv = mesh.UV[ti]
        image = None
        if mesh.texture is not None:
            from PIL import Image

            image = Image.fromarray(mesh.texture)
        visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
        if mesh.colors is not None:
            dropped.append("vertex colours (the file keeps UVs and texture)")
        if mesh.texture is not None and ext == "ply":
            dropped.append("the texture image (PLY keeps UVs only; save the image separately or use OBJ/GLB)")
        tm = trimesh.Trimesh(V, F, visual=visual, process=False)
    else:
        if mesh.UV is not None:
            dropped.append("UVs")
        tm = trimesh.Trimesh(mesh.V, mesh.F, process=False)
        if mesh.colors is not None:
            if ext in ("ply", "obj", "glb", "gltf"):
                tm.visual = trimesh.visual.ColorVisuals(tm, vertex_colors=np.round(mesh.colors * 255).astype(np.uint8))
            else:
                dropped.append("vertex colours")
    return tm, dropped


_PLAIN_OBJ_SKIP = ("o", "g", "s")


def _plain_obj(text: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(V, F)`` of an OBJ made only of ``v x y z`` and triangle ``f a b c`` lines (positive
    indices; comments, blank, ``o``, ``g`` and ``s`` lines allowed), read with NumPy; None for
    anything else (normals, UVs, materials, colours, polygons, ``/``, negative or zero
    indices), which trimesh reads."""
    vs, fs = [], []
    for line in text.splitlines():
        if line.startswith("v "):
            vs.append(line[2:])
        elif line.startswith("f "):
            fs.append(line[2:])
        else:
            t = line.split(None, 1)
            if t and t[0][0] != "#" and t[0] not in _PLAIN_OBJ_SKIP:
                return None
    if not vs or not fs:
        return None
    fj = " ".join(fs)
    if "/" in fj or "-" in fj:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            V = np.fromstring(" ".join(vs), dtype=np.float64, sep=" ")
            F = np.fromstring(fj, dtype=np.int64, sep=" ")
    except (ValueError, DeprecationWarning):
        return None
    if V.size != 3 * len(vs) or F.size != 3 * len(fs) or F.min() < 1:
        return None
    V, F = V.reshape(-1, 3), F.reshape(-1, 3) - 1
    if F.max() >= len(V):
        return None  # out of range: trimesh's message
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    if not used.all():  # like trimesh: vertices no face uses are dropped, the others keep their order
        new = np.cumsum(used) - 1
        V, F = V[used], new[F]
    return V, F


def _check_obj_indices(path: Path, text: str) -> None:
    """OBJ indices are 1-based (negative: relative to the end); 0 is invalid, and trimesh
    would read it as the last vertex."""
    import re

    m = re.search(r"^[ \t]*f[ \t][^\n]*?(?<=[ \t])0(?=[/ \t\r]|$)", text, re.M)
    if m:
        line = text.count("\n", 0, m.start()) + 1
        raise MeshFormatError(f"{path.name}, line {line}: face index 0 (OBJ indices start at 1)")


def _obj_digits(V: np.ndarray) -> int:
    """Decimals that keep ~9 significant digits of the largest coordinate (8 fixed
    decimals would write a head scaled by 1e-9 as all zeros)."""
    m = float(np.abs(V).max()) if len(V) else 1.0
    if not np.isfinite(m) or m == 0.0:
        return 8
    return int(np.clip(9 - np.floor(np.log10(m)), 8, 340))


def save_mesh(path: str | os.PathLike, mesh: Mesh | None = None, *, V=None, F=None, colors=None, UV=None,
              overwrite: bool = True) -> None:
    """Write a mesh atomically (temp file + rename); format from the extension.

    Give either a :class:`Mesh` or bare arrays (``V``, ``F`` and optional per-vertex
    ``colors``/``UV``).  What each format keeps: OBJ and GLB — UVs + texture, or vertex
    colours; PLY — UVs (no image) or vertex colours; OFF, STL — geometry only.
    Attributes a format cannot hold are reported with a :class:`GeofaceWarning`, never
    dropped silently.  PLY, STL and GLB store coordinates as float32; OBJ keeps about 9
    significant digits whatever the scale.
    OBJ files with a texture also get their ``.mtl`` and image beside them, named after the
    mesh (:func:`companion_names`), so meshes in one folder never share (or clobber) a texture.
    ``overwrite=False`` refuses (``OutputError``) to replace the file or any of its companions.
    """
    import trimesh

    from .._io import OutputError

    path = Path(path)
    ext = format_of(path)
    if mesh is None:
        if V is None or F is None:
            raise InvalidMeshError("save_mesh needs a Mesh or V and F")
        mesh = Mesh.from_vertex_uv(V, F, UV, colors=colors)
    if not np.isfinite(mesh.V).all() or np.abs(mesh.V).max(initial=0.0) > 1e300:
        raise InvalidMeshError("vertex coordinates must be finite and below 1e300 in magnitude")
    tm, dropped = _to_trimesh(mesh, ext)
    if dropped:
        warnings.warn(f"{path.name}: .{ext} cannot store {', '.join(dropped)}; not written", GeofaceWarning, stacklevel=2)
    if ext == "obj":
        from trimesh.exchange.obj import export_obj

        mtl = f"{path.stem}.mtl"
        digits = _obj_digits(mesh.V)
        if mesh.colors is None and digits <= objtext.MAX_DIGITS:
            text, files = _fast_obj(tm, mtl, digits)
        else:
            result = export_obj(tm, include_texture=True, include_normals=False, mtl_name=mtl, return_texture=True,
                                digits=digits)
            text, files = result if isinstance(result, tuple) else (result, {})
        if mesh.texture is None:  # UVs without an image: no placeholder picture (trimesh writes a 2x2 grey one)
            files = {k: without_maps(v) for k, v in files.items() if k.endswith(".mtl")}
        files = name_companions(path, files)
        refuse_existing([path, *(path.parent / n for n in files)], overwrite, OutputError)
        with atomic_group(path, files) as (tmp_main, tmp_files):
            Path(tmp_main).write_bytes(text if isinstance(text, bytes) else text.encode())
            for name, data in files.items():
                Path(tmp_files[name]).write_bytes(data)
        return
    refuse_existing([path, *companion_names(path)], overwrite, OutputError)
    data = trimesh.exchange.export.export_mesh(tm, file_obj=None, file_type=ext)
    if isinstance(data, dict):  # gltf returns several files: one JSON and one buffer, named after the mesh
        from .formats import gltf_one_buffer

        main, side = gltf_one_buffer(path, data)
        with atomic_group(path, side) as (tmp_main, tmp_files):
            Path(tmp_main).write_bytes(main)
            for name, blob in side.items():
                Path(tmp_files[name]).write_bytes(blob)
        return
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data if isinstance(data, bytes) else data.encode())


