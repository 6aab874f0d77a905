"""Geometry image → mesh.

One vertex per covered pixel (position from the image and the bounding box in ``meta``);
each 2×2 block of covered pixels becomes two triangles split along the block's shorter 3D
diagonal, a block with three covered pixels one triangle.  UVs are the pixel centres, so the
texture image itself textures the result, and the normal image is an object-space normal
map for it.  Faces are oriented like the source mesh (``meta['uv_orientation']``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InvalidGeometryImageError
from ..mesh.io import Mesh
from .image import GeometryImage

__all__ = ["reconstruct", "save_reconstruction", "pixel_uv", "MAX_SMOOTH"]

#: the most Laplacian smoothing iterations (each moves vertices by half the Laplacian)
MAX_SMOOTH = 1000


def pixel_uv(N: int) -> np.ndarray:
    """``(N, N, 2)`` UV of every pixel centre (the texture-image grid)."""
    from .raster import pixel_grid_uv

    return pixel_grid_uv(N, align_corners=False)


def _laplacian_smooth(V, F, iterations, fixed):
    from ..mesh.core import vertex_adjacency

    A = vertex_adjacency(F, len(V))
    deg = np.asarray(A.sum(1)).ravel()
    V = V.copy()
    for _ in range(iterations):
        avg = (A @ V) / np.maximum(deg, 1)[:, None]
        V = np.where(fixed[:, None], V, 0.5 * V + 0.5 * avg)
    return V


def reconstruct(gi: GeometryImage, *, smooth: int = 0, frame: str = "input") -> Mesh:
    """Mesh of a geometry image (see module docs).

    ``smooth``: iterations of Laplacian smoothing (λ = 0.5) of the interior vertices, to
    remove the staircase of quantised positions in flat areas; 0 keeps pixel positions.
    ``frame``: "input" (default: where the input mesh was) or "stored" (upright as the images
    store it: x right, y up, z front; see :meth:`GeometryImage.positions`).
    Per-vertex colours come from the texture channels when present; the texture image
    (8-bit) is attached with per-vertex UVs at the pixel centres.
    """
    if not isinstance(gi, GeometryImage):
        raise InvalidGeometryImageError("reconstruct needs a GeometryImage")
    N = gi.resolution
    mask = np.asarray(gi.mask, bool)
    if mask.shape != (N, N):
        raise InvalidGeometryImageError(f"mask must be {N}x{N}")
    if int(smooth) != smooth or not 0 <= smooth <= MAX_SMOOTH:
        raise InvalidGeometryImageError(f"smooth must be an integer in 0..{MAX_SMOOTH}; got {smooth!r}")
    P = gi.positions(frame)
    if not np.isfinite(P).all():
        raise InvalidGeometryImageError("position image has non-finite values")
    index = np.full((N, N), -1, np.int64)
    index[mask] = np.arange(int(mask.sum()))
    if mask.sum() < 3:
        raise InvalidGeometryImageError("fewer than three covered pixels: nothing to reconstruct")
    V = P[mask]
    a = index[:-1, :-1]  # (i, j)
    b = index[1:, :-1]  # (i+1, j)
    c = index[:-1, 1:]  # (i, j+1)
    d = index[1:, 1:]  # (i+1, j+1)
    # counter-clockwise in UV (v up): a -> b -> d and a -> d -> c, or split along b-c
    full = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    da = np.linalg.norm(P[:-1, :-1] - P[1:, 1:], axis=2)
    db = np.linalg.norm(P[1:, :-1] - P[:-1, 1:], axis=2)
    ad = full & (da <= db)
    bc = full & ~ad
    tris = [
        np.stack([a[ad], b[ad], d[ad]], 1), np.stack([a[ad], d[ad], c[ad]], 1),
        np.stack([a[bc], b[bc], c[bc]], 1), np.stack([b[bc], d[bc], c[bc]], 1),
    ]
    three = ((a >= 0).astype(int) + (b >= 0) + (c >= 0) + (d >= 0)) == 3
    for missing, tri in (
        (a < 0, (b, d, c)), (b < 0, (a, d, c)), (c < 0, (a, b, d)), (d < 0, (a, b, c)),
    ):
        sel = three & missing
        tris.append(np.stack([t[sel] for t in tri], 1))
    F = np.concatenate(tris).astype(np.int64)
    if gi.meta.get("uv_orientation", 1) < 0:
        F = F[:, ::-1].copy()
    if len(F) == 0:
        raise InvalidGeometryImageError("no 2x2 block of covered pixels: nothing to reconstruct")
    if smooth:
        from ..mesh.core import boundary_loops

        fixed = np.zeros(len(V), bool)
        for loop in boundary_loops(F):
            fixed[loop] = True
        V = _laplacian_smooth(V, F, int(smooth), fixed)
    UV = pixel_uv(N)[mask]
    colors = texture = None
    if gi.has("texture"):
        rgb = gi.modality("texture").transpose(1, 2, 0)
        colors = rgb[mask].astype(np.float64)
        texture = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    # drop unreferenced vertices (isolated covered pixels)
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        F = remap[F]
        V, UV = V[used], UV[used]
        colors = colors[used] if colors is not None else None
    return Mesh(V, F, UV=UV, FUV=F.copy(), colors=colors, texture=texture)


def save_reconstruction(path: str | os.PathLike, mesh: Mesh, gi: GeometryImage | None = None, *,
                        overwrite: bool = True) -> None:
    """Write a reconstruction; for OBJ also the texture (via the MTL) and, when the image has
    normals, an 8-bit object-space normal map ``<stem>_normal.png`` (named in an MTL comment only:
    MTL has no key for object-space normals, and importers would read ``map_Bump`` or ``norm`` as a
    bump or tangent-space map).  With
    ``overwrite=False`` nothing is written if the mesh or any of its files exists."""
    from .._io import OutputError
    from ..mesh.io import refuse_existing, companion_names, save_mesh

    path = Path(path)
    refuse_existing([path, *companion_names(path)], overwrite, OutputError)
    if path.suffix.lower() == ".obj" and mesh.texture is not None:
        # with a texture OBJ keeps UVs + image; keep vertex colours out of the OBJ
        mesh = Mesh(mesh.V, mesh.F, UV=mesh.UV, FUV=mesh.FUV, texture=mesh.texture)
    save_mesh(path, mesh, overwrite=overwrite)
    if path.suffix.lower() == ".obj" and gi is not None and gi.has("normal"):
        from .._io import atomic_path
        from .image import import_cv2

        import_cv2()
        # object-space normals of the reconstructed mesh, which is where the input was
        n = gi.normals()
        nmap = np.round(np.clip((n + 1.0) * 0.5, 0, 1) * 255).astype(np.uint8)
        name = f"{path.stem}_normal.png"
        with atomic_path(path.parent / name) as tmp:
            from .._io import write_image

            write_image(tmp, nmap[:, :, ::-1])
        mtl = path.with_suffix(".mtl")
        if mtl.is_file():
            text = mtl.read_text()
            if name not in text:
                # a comment, not a key: importers read map_Bump / bump / norm as a height or
                # tangent-space map, and MTL has no key for an object-space one
                text = text.rstrip("\n") + (f"\n# {name}: object-space normal map (RGB = (n + 1) / 2 in the mesh's "
                                            "frame), not a tangent-space or bump map; left out of the material\n")
                with atomic_path(mtl) as tmp:
                    Path(tmp).write_text(text)
