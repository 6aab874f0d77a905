"""What the web viewer shows: items loaded from paths, and the colours, textures and lines it
draws them with (:mod:`geoface.webview`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._lazy import lazy_import
from ..errors import GeofaceError

DEFAULT_PORT = 8080
GREY_COLOR = (204, 199, 189)
BOUNDARY_COLOR = (230, 40, 40)


def import_viser():
    return lazy_import("viser", "geoface view --web (pip install 'geoface[web]')")


def item_kind(path) -> str:
    """What a path holds: "gimage", "splat", "avatar" or "mesh"."""
    p = Path(path)
    if not p.exists():
        raise GeofaceError(f"{p}: no such file or folder")
    if p.is_dir():
        if any((q / "meta.json").is_file() and (q / "position.png").is_file() for q in (p, p / "aug0")):
            return "gimage"
        if (p / "config.json").is_file() and (p / "model.safetensors").is_file():
            return "avatar"
        raise GeofaceError(f"{p}: a folder that is neither a geometry image (meta.json + position.png) nor an "
                           "avatar model (`talk train` / `hmd train`: config.json + model.safetensors)")
    if p.suffix.lower() == ".ply":
        with open(p, "rb") as f:
            head = f.read(4096)
        if b"f_dc_0" in head and b"opacity" in head:
            return "splat"
    return "mesh"


# ----------------------------------------------------------------------------- items
@dataclass
class ViewItem:
    path: Path
    kind: str
    V: np.ndarray            # a surface for the layout (and the camera); splats: their means
    F: np.ndarray | None
    name: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def lo(self):
        return self.V.min(0)

    @property
    def hi(self):
        return self.V.max(0)


def load_item(path: Path, kind: str, drive=None, fps: float = 25.0) -> ViewItem:
    if kind == "mesh":
        from ..mesh.io import load_mesh

        m = load_mesh(path)
        return ViewItem(path, kind, m.V, m.F, path.name, {"mesh": m})
    if kind == "gimage":
        from ..gimage import load_gimage, reconstruct

        folder = path if (path / "position.png").is_file() else path / "aug0"
        gi = load_gimage(folder)
        m = reconstruct(gi)
        return ViewItem(path, kind, m.V, m.F, path.name, {"mesh": m, "gi": gi, "folder": folder})
    if kind == "splat":
        from ..splat.ply import load_ply

        g = load_ply(path)
        means = g.means.detach().numpy().astype(np.float64)
        return ViewItem(path, kind, means, None, path.name, {"gaussians": g})
    if kind == "avatar":
        from ..drive.avatars import avatar_drive

        if drive is None:
            raise GeofaceError(f"{path}: an avatar needs something to drive it: --drive WAV or a `talk synth` "
                               "folder (talking avatars), --drive USAGE_DIR (headset removal)")
        d = avatar_drive(path, drive, fps=fps)
        means = d.gaussians(0).means.detach().numpy().astype(np.float64)
        return ViewItem(path, kind, means, None, path.name, {"drive": d})
    raise GeofaceError(f"unknown item kind {kind!r}")


def _colormap(values: np.ndarray, lo: float, hi: float, name: str = "viridis") -> np.ndarray:
    """Values → (n, 3) uint8 through a matplotlib colour map (NaN: magenta)."""
    from matplotlib import colormaps

    t = np.clip((np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = (colormaps[name](np.nan_to_num(t))[:, :3] * 255).astype(np.uint8)
    rgb[~np.isfinite(values)] = (255, 0, 255)
    return rgb


def uv_distortion_colors(mesh, metric: str = "qc") -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """(V2, F2, per-face RGB uint8, (lo, hi)) — the mesh split at UV seams, coloured by the
    quasi-conformal ratio (1 = conformal; 98th percentile at the top of the scale) or the log area
    ratio (0 = area-preserving; symmetric scale); flipped triangles magenta."""
    from ..param.metrics import distortion
    from ..viz import split_corner_uvs

    if mesh.UV is None:
        raise GeofaceError("UV distortion needs a mesh with UVs")
    V2, F2, uv2, _ = split_corner_uvs(mesh.V, mesh.F, mesh.UV, mesh.FUV)
    d = distortion(V2, F2, uv2)
    v = np.asarray(d.qc if metric == "qc" else d.log_area, np.float64).copy()
    v[np.asarray(d.flipped, bool)] = np.nan
    fin = v[np.isfinite(v)]
    if metric == "qc":
        lo, hi, cmap = 1.0, max(float(np.quantile(fin, 0.98)) if len(fin) else 2.0, 1.05), "viridis"
    else:
        a = max(float(np.quantile(np.abs(fin), 0.98)) if len(fin) else 1.0, 0.05)
        lo, hi, cmap = -a, a, "coolwarm"
    return V2, F2, _colormap(v, lo, hi, cmap), (lo, hi)


def import_trimesh(V, F, *, vertex_colors=None, face_colors=None, uv=None, texture=None, flat=False):
    import trimesh

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    if face_colors is not None or flat:  # one vertex per corner: flat normals, per-face colours
        Vc = V[F].reshape(-1, 3)
        Fc = np.arange(len(Vc)).reshape(-1, 3)
        vc = None
        if face_colors is not None:
            vc = np.repeat(np.asarray(face_colors)[:, :3], 3, axis=0)
        elif vertex_colors is not None:
            vc = np.asarray(vertex_colors)[F].reshape(-1, np.asarray(vertex_colors).shape[1])
        uvc = None if uv is None else np.asarray(uv)[F].reshape(-1, 2)
        V, F, vertex_colors, uv = Vc, Fc, vc, uvc
    tm = trimesh.Trimesh(V, F, process=False)
    if texture is not None and uv is not None:
        from PIL import Image

        # a PBR material of its own: trimesh's default one multiplies the texture by 0.4 and
        # leaves glTF's metallicFactor at 1 (a metal), which drew textured heads at half brightness
        mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(texture),
                                                  baseColorFactor=[255, 255, 255, 255], metallicFactor=0.0,
                                                  roughnessFactor=1.0)
        tm.visual = trimesh.visual.TextureVisuals(uv=np.asarray(uv, np.float64), material=mat)
    elif vertex_colors is not None:
        c = np.asarray(vertex_colors)
        c = c / 255.0 if c.dtype == np.uint8 else np.clip(c, 0, 1)
        # glTF's COLOR_0 is linear, and the page turns it back to sRGB: without this a colour
        # would show lighter and greyer than it is
        rgb = c[:, :3]
        lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
        c = np.concatenate([lin, c[:, 3:]], axis=1)
        tm.visual = trimesh.visual.ColorVisuals(tm, vertex_colors=np.round(c * 255).astype(np.uint8))
    return tm


def boundary_segments(V, F) -> np.ndarray:
    """(k, 2, 3) segments of every boundary edge (edges with one face)."""
    from ..mesh.core import edge_topology

    et = edge_topology(np.asarray(F, np.int64))
    b = et.E[et.edge_faces == 1]
    return np.asarray(V, np.float64)[b]


def gimage_images(gi, folder: Path) -> dict:
    """name → (N, N, 3) uint8 image of a geometry image's modalities, mask and ROI."""
    from ..viz import gimage_tiles

    tiles = dict(gimage_tiles(gi))
    m = np.asarray(gi.mask, bool)
    roi = Path(folder) / "roi.png"
    if roi.is_file():
        import cv2

        r = cv2.imread(str(roi), cv2.IMREAD_GRAYSCALE)
        if r is not None and r.shape == m.shape:
            base = tiles.get("texture", tiles.get("normal", tiles["mask"])).astype(np.float32)
            over = base * 0.45 + np.array([255.0, 150.0, 40.0]) * 0.55 * (r[..., None] > 127)
            tiles["ROI"] = np.clip(np.where(r[..., None] > 127, over, base * 0.6), 0, 255).astype(np.uint8)
    return tiles


def glb_bytes(tm) -> bytes:
    """``tm`` as a GLB whose every primitive has a dielectric material: glTF's default (and a
    primitive with no material, as vertex colours are exported) is a full metal, which the page
    draws dark and tinted."""
    import json
    import struct

    blob = tm.export(file_type="glb")
    n_json = struct.unpack_from("<I", blob, 12)[0]
    doc = json.loads(blob[20:20 + n_json])
    rest = blob[20 + n_json:]
    mats = doc.setdefault("materials", [])
    for m in mats:
        m.setdefault("pbrMetallicRoughness", {})["metallicFactor"] = 0.0
    plain = None
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            if "material" not in prim:
                if plain is None:
                    plain = len(mats)
                    mats.append({"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                                          "roughnessFactor": 1.0}})
                prim["material"] = plain
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body
