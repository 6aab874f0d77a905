"""Geometry images: position, normal and texture of a parameterized disk on an N×N grid.

In memory a :class:`GeometryImage` is a ``(C, N, N)`` float32 array in [0, 1], a coverage
mask and a metadata dict.  Channels, in order: ``position`` (x, y, z normalised by the
bounding box in ``meta``), ``normal`` ((n + 1) / 2 of the unit normal), ``texture`` (RGB).

On disk (a folder): one 16-bit PNG per modality — ``position.png``, ``normal.png``,
``texture.png`` — an 8-bit ``mask.png`` and ``meta.json``.  Values are quantised to
``round(x · 65535)``, so a round trip changes a value by at most half a step (7.6e-6).

Pixel grid (format version 2, ``meta["align_corners"] = true``): pixel ``(i, j)`` samples
UV ``(j / (N - 1), 1 - i / (N - 1))``, so the outermost pixels lie on the square's edges,
where the mesh boundary is mapped.  Version 1 folders (pixel centres at
``((j + 0.5) / N, ...)``, no ``align_corners`` key) still load; ``GeometryImage.align_corners``
tells which grid an image uses.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import GeofaceError, InvalidGeometryImageError
from ..mesh.core import check_mesh, signed_uv_areas, vertex_normals
from .raster import interpolate, interpolate_corners, rasterize_faces, sample_texture

__all__ = ["GeometryImage", "geometry_image", "gimage_from_samples", "save_gimage", "load_gimage", "MODALITIES", "FORMAT_VERSION"]

FORMAT_VERSION = 2
MODALITIES = {"position": ("px", "py", "pz"), "normal": ("nx", "ny", "nz"), "texture": ("r", "g", "b")}
Q = 65535.0


@dataclass(frozen=True)
class GeometryImage:
    """image : (C, N, N) float32 in [0, 1]; mask : (N, N) bool coverage; meta : dict with
    ``bbox_min``, ``bbox_max``, ``channels``, ``resolution``, ``version`` and whatever the
    producer adds (``param`` statistics, ``corners``, ``uv_orientation``)."""

    image: np.ndarray
    mask: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def resolution(self) -> int:
        return int(self.image.shape[-1])

    @property
    def channels(self) -> list:
        return list(self.meta["channels"])

    def modality(self, name: str) -> np.ndarray:
        """``(3, N, N)`` slice of one modality."""
        if name not in MODALITIES:
            raise InvalidGeometryImageError(f"unknown modality {name!r}; use one of {', '.join(MODALITIES)}")
        ch = self.channels
        try:
            idx = [ch.index(c) for c in MODALITIES[name]]
        except ValueError:
            raise InvalidGeometryImageError(f"this geometry image has no {name} channels") from None
        return self.image[idx]

    def has(self, name: str) -> bool:
        return all(c in self.meta["channels"] for c in MODALITIES[name])

    @property
    def to_input(self) -> np.ndarray:
        """``(3, 3)`` rotation from the stored frame to the input mesh's: ``geoface convert``
        stores heads upright (x right, y up, z front: the same pixels whatever the file's axis
        convention) and keeps the rotation back in ``meta["frame"]["to_input"]``; identity for
        images without one."""
        fr = self.meta.get("frame")
        if not isinstance(fr, dict) or "to_input" not in fr:
            return np.eye(3)
        R = np.asarray(fr["to_input"], np.float64)
        if R.shape != (3, 3) or not np.isfinite(R).all() or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise InvalidGeometryImageError("meta.json frame.to_input must be a 3x3 rotation")
        return R

    def positions(self, frame: str = "input") -> np.ndarray:
        """``(N, N, 3)`` positions in the mesh's units: where the input mesh had them
        (``frame="input"``, default) or as stored, upright (``"stored"``)."""
        if frame not in ("input", "stored"):
            raise InvalidGeometryImageError(f"frame must be 'input' or 'stored'; got {frame!r}")
        lo = np.asarray(self.meta["bbox_min"], np.float64)
        hi = np.asarray(self.meta["bbox_max"], np.float64)
        p = self.modality("position").astype(np.float64).transpose(1, 2, 0)
        P = lo + p * (hi - lo)
        return P if frame == "stored" else P @ self.to_input.T

    @property
    def align_corners(self) -> bool:
        """The pixel grid: True (format 2) when the outermost pixels sample the square's
        edges, False (format 1) for pixel centres at ``(j + 0.5) / N``."""
        return bool(self.meta.get("align_corners", False))

    def sample_uv(self) -> np.ndarray:
        """``(N, N, 2)`` parameter-domain UV each pixel samples."""
        from .raster import pixel_grid_uv

        return pixel_grid_uv(self.resolution, self.align_corners)

    def normals(self, frame: str = "input") -> np.ndarray:
        """``(N, N, 3)`` unit normals (zero where uncovered), in the input mesh's frame or as
        stored (see :meth:`positions`)."""
        if frame not in ("input", "stored"):
            raise InvalidGeometryImageError(f"frame must be 'input' or 'stored'; got {frame!r}")
        n = self.modality("normal").astype(np.float64).transpose(1, 2, 0) * 2.0 - 1.0
        L = np.linalg.norm(n, axis=2, keepdims=True)
        n = np.where(L > 0, n / np.maximum(L, 1e-300), 0.0)
        return n if frame == "stored" else n @ self.to_input.T


def _bbox(V, bbox):
    if bbox is None:
        lo, hi = V.min(0), V.max(0)
    else:
        lo, hi = (np.asarray(b, np.float64) for b in bbox)
        if lo.shape != (3,) or hi.shape != (3,):
            raise InvalidGeometryImageError("bbox must be (min xyz, max xyz)")
        if (V < lo - 1e-12).any() or (V > hi + 1e-12).any():
            raise InvalidGeometryImageError("the mesh does not fit in the given bbox")
    hi = np.where(hi - lo > 0, hi, lo + 1e-12)
    return lo, hi


def geometry_image(
    V,
    F,
    uv,
    N: int = 512,
    *,
    normals: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    texture: np.ndarray | None = None,
    tex_uv: np.ndarray | None = None,
    tex_fuv: np.ndarray | None = None,
    bbox=None,
    meta: dict | None = None,
    raster: tuple | None = None,
) -> GeometryImage:
    """Rasterize a mesh with a map ``uv (n, 2)`` into the unit square at ``N × N``.

    Parameters
    ----------
    normals : (n, 3) per-vertex normals (default: area-weighted vertex normals)
    colors : (n, 3|4) per-vertex colours in [0, 1] → ``texture`` channels, or
    texture, tex_uv, tex_fuv : a texture image with its own UVs (``tex_uv (t, 2)`` and per-face
        corners ``tex_fuv (m, 3)`` for the faces ``F``) → the texture is sampled through them
    bbox : (min, max) for the position normalisation (default: the mesh's own bounding box;
        give a fixed one to make a dataset share one scale)
    raster : ``rasterize_faces(F, uv, N, align_corners=True)`` when the caller already has it
        (to interpolate more attributes over the same pixels without rasterizing twice)
    """
    V, F = check_mesh(V, F)
    uv = np.asarray(uv, np.float64)
    if uv.shape != (len(V), 2) or not np.isfinite(uv).all():
        raise InvalidGeometryImageError(f"uv must be a finite ({len(V)}, 2) array")
    face, bary = rasterize_faces(F, uv, N, align_corners=True) if raster is None else raster
    if face.shape != (N, N):
        raise InvalidGeometryImageError(f"raster must be {N}x{N}; got {face.shape}")
    lo, hi = _bbox(V, bbox)
    mask = face >= 0
    pos = interpolate(face, bary, F, (V - lo) / (hi - lo))
    nrm = vertex_normals(V, F) if normals is None else np.asarray(normals, np.float64)
    if nrm.shape != V.shape:
        raise InvalidGeometryImageError(f"normals must have shape {V.shape}")
    nimg = interpolate(face, bary, F, nrm)
    tex = None
    if texture is not None:
        if tex_uv is None or tex_fuv is None:
            raise InvalidGeometryImageError("a texture image needs tex_uv and tex_fuv")
        tex_fuv = np.asarray(tex_fuv, np.int64)
        if tex_fuv.shape != F.shape:
            raise InvalidGeometryImageError(f"tex_fuv must have the shape of F {F.shape}")
        tuv = interpolate_corners(face, bary, np.asarray(tex_uv, np.float64)[tex_fuv])
        rgb = sample_texture(texture, tuv.transpose(1, 2, 0))[..., :3]
        if rgb.shape[-1] == 1:
            rgb = np.repeat(rgb, 3, axis=-1)
        scale = 255.0 if np.asarray(texture).dtype == np.uint8 else 1.0
        tex = (rgb / scale).transpose(2, 0, 1) * mask
    elif colors is not None:
        C = np.asarray(colors, np.float64)
        if C.ndim != 2 or C.shape[0] != len(V) or C.shape[1] not in (3, 4):
            raise InvalidGeometryImageError(f"colors must have shape ({len(V)}, 3|4)")
        tex = interpolate(face, bary, F, C[:, :3])
    orient = 1 if signed_uv_areas(F, uv).sum() >= 0 else -1
    return _assemble(pos, nimg, tex, mask, lo, hi, orient, meta)


def gimage_from_samples(positions: np.ndarray, normals: np.ndarray, mask: np.ndarray, colors: np.ndarray | None = None, *,
                        uv_orientation: int = 1, bbox=None, meta: dict | None = None) -> GeometryImage:
    """A geometry image from per-pixel samples: ``positions (N, N, 3)`` and ``normals (N, N, 3)``
    (object space, any length; normalised here) and optionally ``colors (N, N, 3)`` in [0, 1],
    valid where ``mask (N, N)``.  What :func:`geometry_image` makes from a mesh's vertices, for
    samples taken elsewhere (the full-resolution surface under a decimated proxy, in
    ``geoface convert``).  ``bbox`` defaults to the valid positions' bounding box."""
    mask = np.asarray(mask, bool)
    P = np.asarray(positions, np.float64)
    if mask.ndim != 2 or mask.shape[0] != mask.shape[1] or P.shape != (*mask.shape, 3):
        raise InvalidGeometryImageError(f"positions must be (N, N, 3) over an (N, N) mask; got {P.shape} and {mask.shape}")
    if not mask.any() or not np.isfinite(P[mask]).all():
        raise InvalidGeometryImageError("positions must be finite on a non-empty mask")
    Nn = np.asarray(normals, np.float64)
    if Nn.shape != P.shape:
        raise InvalidGeometryImageError(f"normals must have the shape of positions {P.shape}; got {Nn.shape}")
    lo, hi = _bbox(P[mask], bbox)
    m3 = mask[None]
    pos = np.where(m3, (P.transpose(2, 0, 1) - lo[:, None, None]) / (hi - lo)[:, None, None], 0.0)
    tex = None
    if colors is not None:
        C = np.asarray(colors, np.float64)
        if C.shape != P.shape:
            raise InvalidGeometryImageError(f"colors must have the shape of positions {P.shape}; got {C.shape}")
        tex = np.where(m3, C.transpose(2, 0, 1), 0.0)
    return _assemble(pos, np.where(m3, Nn.transpose(2, 0, 1), 0.0), tex, mask, lo, hi, int(uv_orientation), meta)


def _assemble(pos, nimg, tex, mask, lo, hi, orient, meta) -> GeometryImage:
    """The image from channel-first normalised positions, normals (unit-normalised here) and
    optional colours over ``mask``."""
    L = np.linalg.norm(nimg, axis=0, keepdims=True)
    nimg = np.where(L > 0, nimg / np.maximum(L, 1e-300), 0.0)
    chans = [pos, (nimg + 1.0) * 0.5 * mask]
    names = [*MODALITIES["position"], *MODALITIES["normal"]]
    if tex is not None:
        chans.append(tex)
        names += list(MODALITIES["texture"])
    img = np.clip(np.concatenate(chans, 0), 0.0, 1.0).astype(np.float32)
    N = mask.shape[0]
    m = {
        "version": FORMAT_VERSION,
        "resolution": int(N),
        "align_corners": True,
        "channels": names,
        "bbox_min": np.asarray(lo, float).tolist(),
        "bbox_max": np.asarray(hi, float).tolist(),
        "uv_orientation": orient,
        "coverage": float(mask.mean()),
    }
    if meta:
        m.update(meta)
    return GeometryImage(img, mask, m)


# --------------------------------------------------------------------------- disk format
def import_cv2():
    from .._lazy import lazy_import

    return lazy_import("cv2", "16-bit PNG geometry images")


def _write_png16(path: Path, rgb: np.ndarray) -> None:
    import_cv2()  # a clear message when OpenCV is missing
    from ..images import save_image

    save_image(path, np.clip(rgb, 0.0, 1.0), bits=16, atomic=False)  # round(v * Q), Q = 65535


def read_png(path: Path, expect: int | None = None) -> np.ndarray:
    """The file's own integers (RGB order, alpha dropped); a one-line InvalidGeometryImageError
    when it is missing, not a PNG, or not ``expect`` pixels square."""
    from ..images import read_image

    import_cv2()
    if not path.is_file():
        raise InvalidGeometryImageError(f"missing {path.name} in {path.parent}")
    try:
        img = read_image(path, "any", as_float=False, expect_size=None if expect is None else (expect, expect))
    except GeofaceError as e:
        raise InvalidGeometryImageError(str(e).replace("not a readable image", "not a readable PNG")) from None
    return img[..., :3] if img.ndim == 3 else img


def save_gimage(folder: str | os.PathLike, gi: GeometryImage, *, overwrite: bool = True) -> Path:
    """Write ``gi`` into ``folder`` (created; replaced as a whole, never left half-written;
    an existing folder is refused when ``overwrite`` is False)."""
    from .._io import atomic_dir

    if not isinstance(gi, GeometryImage):
        raise InvalidGeometryImageError(f"save_gimage writes a GeometryImage; got {type(gi).__name__}")
    folder = Path(folder)
    if folder.exists() and not overwrite:
        raise InvalidGeometryImageError(f"{folder} exists")
    with atomic_dir(folder, overwrite=True) as tmp:
        write_gimage_files(tmp, gi)
    return folder


def write_gimage_files(folder: Path, gi: GeometryImage) -> None:
    """The files of ``gi`` into an existing folder (no atomicity; see :func:`save_gimage`)."""
    for name in MODALITIES:
        if gi.has(name):
            _write_png16(folder / f"{name}.png", gi.modality(name).transpose(1, 2, 0))
    from .._io import write_image

    write_image(folder / "mask.png", gi.mask.astype(np.uint8) * 255)
    (folder / "meta.json").write_text(json.dumps(gi.meta, indent=2))


def load_gimage(folder: str | os.PathLike) -> GeometryImage:
    """Read a geometry-image folder, validating sizes, bit depth and metadata."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidGeometryImageError(f"{folder} is not a geometry-image folder")
    mp = folder / "meta.json"
    if not mp.is_file():
        raise InvalidGeometryImageError(f"{folder} has no meta.json")
    try:
        meta = json.loads(mp.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InvalidGeometryImageError(f"{mp} is not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise InvalidGeometryImageError(f"{mp} must hold a JSON object; got {type(meta).__name__}")
    for key in ("version", "resolution", "channels", "bbox_min", "bbox_max"):
        if key not in meta:
            raise InvalidGeometryImageError(f"{mp} lacks '{key}'")
    if isinstance(meta["version"], bool) or not isinstance(meta["version"], int) or meta["version"] < 1:
        raise InvalidGeometryImageError(f"{mp}: version must be a positive integer; got {meta['version']!r}")
    ch = meta["channels"]
    if not isinstance(ch, list) or not all(isinstance(c, str) for c in ch):
        raise InvalidGeometryImageError(f"{mp}: channels must be a list of names; got {ch!r}")
    for key in ("bbox_min", "bbox_max"):
        b = meta[key]
        if not isinstance(b, list) or len(b) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in b):
            raise InvalidGeometryImageError(f"{mp}: {key} must be three numbers; got {b!r}")
    if "uv_orientation" in meta and meta["uv_orientation"] not in (1, -1):
        raise InvalidGeometryImageError(f"{mp}: uv_orientation must be 1 or -1; got {meta['uv_orientation']!r}"[:200])
    if "align_corners" in meta and not isinstance(meta["align_corners"], bool):
        raise InvalidGeometryImageError(f"{mp}: align_corners must be true or false; got {meta['align_corners']!r}")
    if meta["version"] > FORMAT_VERSION:
        raise InvalidGeometryImageError(f"{mp}: format version {meta['version']} is newer than this geoface ({FORMAT_VERSION})")
    N = meta["resolution"]
    if isinstance(N, bool) or not isinstance(N, int) or not 2 <= N <= 65536:
        raise InvalidGeometryImageError(f"{mp}: bad resolution {N!r}")
    lo, hi = np.asarray(meta["bbox_min"], float), np.asarray(meta["bbox_max"], float)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()) or (hi <= lo).any():
        raise InvalidGeometryImageError(f"{mp}: bad bounding box")
    chans = []
    names = []
    for name, cn in MODALITIES.items():
        if not all(c in meta["channels"] for c in cn):
            continue
        img = read_png(folder / f"{name}.png", expect=N)
        if img.dtype != np.uint16:
            raise InvalidGeometryImageError(f"{name}.png must be 16-bit; got {img.dtype}")
        if img.shape != (N, N, 3):
            raise InvalidGeometryImageError(f"{name}.png must be {N}x{N} RGB; got {img.shape}")
        chans.append(img.transpose(2, 0, 1).astype(np.float32) / np.float32(Q))
        names += list(cn)
    if "px" not in names:
        raise InvalidGeometryImageError(f"{folder} has no position image")
    mpng = folder / "mask.png"
    if mpng.is_file():
        m = read_png(mpng, expect=N)
        if m.ndim != 2 or m.shape != (N, N):
            raise InvalidGeometryImageError(f"mask.png must be {N}x{N} grey; got {m.shape}")
        mask = m > 0
    else:
        mask = np.ones((N, N), bool)
    meta["channels"] = names
    return GeometryImage(np.concatenate(chans, 0), mask, meta)
