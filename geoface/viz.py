"""Visual checks: textured meshes, UV distortion, geometry-image montages, mesh comparisons.

pyvista is imported lazily inside the functions (``pip install 'geoface[viz]'``), so
``import geoface`` stays light.  Every plotting function returns the rendered picture as
an ``(H, W, 3) uint8`` array and writes it as a PNG (atomically) when ``screenshot=path``.
Rendering is off-screen when a screenshot is requested or when there is no display
(no ``DISPLAY`` / ``WAYLAND_DISPLAY`` on Linux); otherwise an interactive window opens.
What is drawn, as plain arrays (meshes unpacked, UVs split per vertex, 8-bit colours and
tiles, distances), is :mod:`geoface.viz_arrays`.

Examples
--------
>>> from geoface.synth import procedural_head
>>> from geoface import viz
>>> head = procedural_head(3000, seed=0)
>>> img = viz.plot_mesh((head.V, head.F), colors=head.colors, screenshot="head.png")
>>> img.shape[2]
3
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from ._lazy import lazy_import
from .errors import GeofaceError, InvalidGeometryImageError, InvalidMeshError
from .viz_arrays import check_VF, distances, gimage_tiles, split_corner_uvs, texture_uint8, to_uint8_rgb, unpack_mesh

__all__ = ["has_display", "to_pyvista", "plot_mesh", "turntable", "plot_uv_distortion", "gimage_montage", "compare_meshes",
           "save_png"]

BACKGROUND = (1.0, 1.0, 1.0)
DEFAULT_SIZE = (800, 800)


def _pv():
    pv = lazy_import("pyvista", "geoface.viz")
    _quiet_vtk()
    return pv


def _quiet_vtk() -> None:
    """Off-screen rendering needs no display, but VTK still warns "bad X server connection" on
    stderr (into notebooks and logs) when DISPLAY is unset; keep VTK's log to real errors."""
    try:
        from vtkmodules.vtkCommonCore import vtkLogger
    except ImportError:  # an older VTK without vtkLogger prints no such warning
        return
    if not has_display():
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)


def has_display() -> bool:
    """True when an interactive window can be opened (a display server on Linux)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _off_screen(off_screen: bool | None, screenshot) -> bool:
    if off_screen is not None:
        return bool(off_screen)
    return screenshot is not None or not has_display()


def save_png(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Write an ``(H, W, 3|4) uint8`` RGB(A) image as PNG, atomically (:func:`geoface.images.save_image`)."""
    from .images import save_image

    lazy_import("cv2", "PNG output")
    img = np.asarray(img)
    if img.dtype != np.uint8:
        raise GeofaceError(f"save_png needs a uint8 image; got {img.dtype}")
    save_image(path, img)
    return Path(path)


def to_pyvista(V, F, uv=None, colors=None, scalars=None):
    """A :class:`pyvista.PolyData` from arrays.

    Parameters
    ----------
    V : (n, 3) float; F : (m, 3) int
    uv : (n, 2) float, optional — per-vertex texture coordinates (``active_texture_coordinates``)
    colors : (n, 3|4) float in [0, 1] or uint8, optional — per-vertex colours, point array ``"rgb"``
    scalars : (n,) or (m,) float, optional — point or cell array ``"scalars"``
    """
    pv = _pv()
    V, F = check_VF(V, F)
    faces = np.hstack([np.full((len(F), 1), 3, np.int64), F]).ravel()
    mesh = pv.PolyData(V.copy(), faces)
    if uv is not None:
        uv = np.asarray(uv, np.float64)
        if uv.shape != (len(V), 2):
            raise InvalidMeshError(f"uv must have shape ({len(V)}, 2); got {uv.shape}")
        mesh.active_texture_coordinates = uv
    if colors is not None:
        mesh.point_data["rgb"] = to_uint8_rgb(colors, len(V), "colors")
    if scalars is not None:
        s = np.asarray(scalars, np.float64).ravel()
        if len(s) == len(V):
            mesh.point_data["scalars"] = s
        elif len(s) == len(F):
            mesh.cell_data["scalars"] = s
        else:
            raise InvalidMeshError(f"scalars must have {len(V)} (vertices) or {len(F)} (faces) values; got {len(s)}")
    return mesh


def _plotter(off_screen: bool, window_size, shape=(1, 1)):
    pv = _pv()
    ws = tuple(int(x) for x in (window_size or DEFAULT_SIZE))
    if len(ws) != 2 or min(ws) < 16:
        raise GeofaceError(f"window_size must be two sizes >= 16 like (800, 600); got {window_size}")
    if not off_screen and not has_display():
        raise GeofaceError("no display for an interactive window; pass screenshot=... (or --screenshot) to render off-screen")
    pl = pv.Plotter(off_screen=off_screen, window_size=list(ws), shape=shape)
    pl.set_background(BACKGROUND)
    return pl


def _finish(pl, screenshot, off_screen: bool) -> np.ndarray:
    """Render, grab the picture, write it, and show the window when on-screen."""
    if off_screen:
        img = pl.screenshot(return_img=True)
        pl.close()
    else:  # blocks until the user closes the window; pyvista keeps the last frame
        pl.show()
        img = getattr(pl, "last_image", None)
        if img is None:
            img = np.zeros((0, 0, 3), np.uint8)
    img = np.ascontiguousarray(np.asarray(img)[..., :3], dtype=np.uint8)
    if screenshot is not None and img.size == 0:
        raise GeofaceError(f"no picture to write to {screenshot}: the window gave none back")
    if screenshot is not None:
        save_png(screenshot, img)
    return img


def _add_mesh(pl, mesh_or_VF, texture=None, colors=None, color=None, scalars=None, **kw):
    """Add a mesh to the plotter: textured if it has UVs and a texture, else coloured."""
    pv = _pv()
    V, F, UV, FUV, mcol, mtex = unpack_mesh(mesh_or_VF)
    tex = texture if texture is not None else mtex
    col = colors if colors is not None else mcol
    if tex is not None and UV is not None and scalars is None and colors is None:
        V2, F2, uv2, _ = split_corner_uvs(V, F, UV, FUV)
        poly = to_pyvista(V2, F2, uv=uv2)
        # pyvista's Texture(array) takes row 0 as the top (v = 1), our convention too.
        pl.add_mesh(poly, texture=pv.Texture(texture_uint8(tex)), **kw)
        return poly
    if tex is not None and UV is None and texture is not None:
        raise InvalidMeshError("a texture needs UVs: the mesh has none")
    if scalars is not None:
        poly = to_pyvista(V, F, scalars=scalars)
        pl.add_mesh(poly, scalars="scalars", **kw)
    elif col is not None:
        poly = to_pyvista(V, F, colors=col)
        pl.add_mesh(poly, scalars="rgb", rgb=True, **kw)
    else:
        poly = to_pyvista(V, F)
        pl.add_mesh(poly, color=color or (0.8, 0.78, 0.74), **kw)
    return poly


def plot_mesh(mesh_or_VF, texture=None, *, colors=None, color=None, screenshot=None, window_size=DEFAULT_SIZE,
              off_screen: bool | None = None, view: str = "front", up=None, face=None,
              show_edges: bool = False) -> np.ndarray:
    """Render a mesh: textured (per-corner UVs + texture), vertex-coloured, or plain.

    Parameters
    ----------
    mesh_or_VF : Mesh, SynthHead or (V, F)
    texture : (h, w, 3) uint8, optional — overrides the mesh's texture (row 0 = top, v = 1)
    colors : (n, 3|4) per-vertex colours in [0, 1] (or uint8), optional
    color : a single colour for an uncoloured mesh
    screenshot : path, optional — write the picture as PNG (implies off-screen)
    window_size : (W, H); off_screen : force on/off (default: automatic)
    view : where the camera sits: "front" (the default: facing the mesh, found from the mesh
        itself, see :func:`geoface.mesh.frame.mesh_frame`), "back", "left", "right", "top",
        "bottom", "iso"; or a fixed axis view "xy" (looking down -z), "xz", "yz"
    up : the mesh's up direction ("+y" by default, "+z" for Z-up scans, or three numbers)
    face : vertex indices (or a vertex mask) of the face region, when known: the front is then
        where the face is

    Returns
    -------
    (H, W, 3) uint8 — the rendered picture (after an interactive window: its last frame).
    """
    off = _off_screen(off_screen, screenshot)
    pl = _plotter(off, window_size)
    _add_mesh(pl, mesh_or_VF, texture=texture, colors=colors, color=color, show_edges=show_edges)
    _set_view(pl, view, mesh_or_VF, up=up, face=face)
    return _finish(pl, screenshot, off)


AXIS_VIEWS = ("xy", "xz", "yz")


def _set_view(pl, view: str, mesh_or_VF=None, *, up=None, face=None, frame=None):
    """Point the camera: a named view of the mesh's own frame, or a fixed axis view."""
    from .mesh.frame import VIEWS, mesh_frame

    if view in AXIS_VIEWS:
        getattr(pl, f"view_{view}")()
        pl.reset_camera()
        return
    if view not in VIEWS:
        raise GeofaceError(f"view must be one of {', '.join([*VIEWS, *AXIS_VIEWS])}; got {view!r}")
    if frame is None:
        V, F = unpack_mesh(mesh_or_VF)[:2]
        if face is None and getattr(mesh_or_VF, "face_mask", None) is not None:  # a SynthHead knows its face
            face = mesh_or_VF.face_mask
        frame = mesh_frame(V, F, up=up, face=face)
    pos, focal, vup = frame.camera(view)
    pl.camera_position = [tuple(pos), tuple(focal), tuple(vup)]
    pl.reset_camera()


def turntable(mesh_or_VF, path, *, seconds: float = 6.0, fps: float = 25.0, window_size=DEFAULT_SIZE, up=None,
              face=None, elevation: float = 10.0, quiet: bool | None = None) -> int:
    """A turn around the mesh, starting in front of it, as an MP4 (``geoface.video``). The camera
    circles the up axis once, ``elevation`` degrees above the horizon (a progress line per frame
    rendered unless ``quiet``; the library's default is quiet). Returns the frame count."""
    from .mesh.frame import mesh_frame
    from .progress import progress
    from .video import write_video

    V, F = unpack_mesh(mesh_or_VF)[:2]
    if face is None and getattr(mesh_or_VF, "face_mask", None) is not None:
        face = mesh_or_VF.face_mask
    fr = mesh_frame(V, F, up=up, face=face)
    n = max(2, int(round(float(seconds) * float(fps))))
    pl = _plotter(True, window_size)
    _add_mesh(pl, mesh_or_VF)
    el = np.radians(elevation)
    # far enough that the bounding sphere fits the narrower view angle, with a margin (a tall
    # figure keeps its head and feet in every frame)
    aspect = window_size[0] / window_size[1]
    half = np.radians(pl.camera.view_angle) / 2
    half = min(half, np.arctan(np.tan(half) * aspect))
    dist = 1.08 * fr.radius / np.sin(half)

    def frames():
        try:
            for k in progress(range(n), "turntable", unit="frames", quiet=quiet):
                a = 2 * np.pi * k / n
                d = np.cos(el) * (np.cos(a) * fr.front + np.sin(a) * fr.right) + np.sin(el) * fr.up
                pl.camera_position = [tuple(fr.center + dist * d), tuple(fr.center), tuple(fr.up)]
                pl.reset_camera_clipping_range()
                pl.render()  # pyvista renders only on the first screenshot unless asked after the camera moves
                yield np.asarray(pl.screenshot(return_img=True))[..., :3]
        finally:
            pl.close()

    write_video(frames(), path, fps=fps)
    return n


def plot_uv_distortion(V, F, uv, metric: str = "qc", *, screenshot=None, window_size=DEFAULT_SIZE, off_screen=None,
                       clim=None, show_edges: bool = False) -> np.ndarray:
    """The UV layout, flat in the plane, coloured per triangle by distortion.

    ``metric="qc"``: quasi-conformal ratio (1 = conformal); ``"area"``: log area ratio
    (0 = area preserving).  Flipped (orientation-reversed) triangles are drawn magenta.
    """
    from .param.metrics import distortion

    if metric not in ("qc", "area"):
        raise GeofaceError(f"metric must be 'qc' or 'area'; got {metric!r}")
    V, F = check_VF(V, F)
    uv = np.asarray(uv, np.float64)
    if uv.shape != (len(V), 2):
        raise InvalidMeshError(f"uv must have shape ({len(V)}, 2); got {uv.shape}")
    d = distortion(V, F, uv)
    vals = np.asarray(d.qc if metric == "qc" else d.log_area, np.float64).copy()
    vals[np.asarray(d.flipped, bool)] = np.nan
    finite = vals[np.isfinite(vals)]
    if clim is None:
        if metric == "qc":
            hi = float(np.quantile(finite, 0.98)) if len(finite) else 2.0
            clim = (1.0, max(hi, 1.05))
        else:
            a = float(np.quantile(np.abs(finite), 0.98)) if len(finite) else 1.0
            clim = (-max(a, 0.05), max(a, 0.05))
    flat = np.column_stack([uv, np.zeros(len(uv))])
    off = _off_screen(off_screen, screenshot)
    pl = _plotter(off, window_size)
    poly = to_pyvista(flat, F, scalars=vals)
    title = "QC ratio" if metric == "qc" else "log area"
    pl.add_mesh(poly, scalars="scalars", cmap="viridis" if metric == "qc" else "coolwarm", clim=list(clim),
                nan_color="magenta", show_edges=show_edges, lighting=False,
                scalar_bar_args={"title": title, "color": "black", "vertical": True, "position_x": 0.85, "position_y": 0.1,
                                 "height": 0.8, "width": 0.08})
    pl.view_xy()
    pl.reset_camera()
    return _finish(pl, screenshot, off)


def gimage_montage(gi, *, screenshot=None, surface: bool = False, gap: int = 4, labels: bool = True,
                   tile: int | None = None, window_size=None, off_screen=None) -> np.ndarray:
    """A montage of a geometry image's modalities: position | normal | texture | mask.

    Each tile is ``N × N`` (the modality mapped to 8 bits: position and normal as RGB in
    [0, 1], texture as is, mask white), tiles separated by ``gap`` grey pixels.  With
    ``surface=True`` a 3D rendering of the geometry image (the reconstructed surface,
    textured when it has texture channels) is appended as a last tile: in the frame the images
    store (x right, y up, z front), seen from +z with +y up, so a wrong frame shows there (a head
    stored sideways looks sideways).  ``tile=T`` scales
    every tile to ``T × T`` (nearest neighbour, pixels stay visible; default ``N``).

    Returns an ``(T, k·T + (k-1)·gap, 3) uint8`` image; written as PNG to ``screenshot``.
    """
    if not hasattr(gi, "image") or not hasattr(gi, "mask"):
        raise InvalidGeometryImageError(f"expected a GeometryImage; got {type(gi).__name__}")
    tiles = gimage_tiles(gi)
    N = gi.resolution
    if tile is not None and int(tile) != N:
        if int(tile) < 8:
            raise GeofaceError(f"tile must be at least 8 pixels; got {tile}")
        cv2 = lazy_import("cv2", "geometry-image montage")
        N = int(tile)
        tiles = [(name, cv2.resize(t, (N, N), interpolation=cv2.INTER_NEAREST)) for name, t in tiles]
    if surface:
        from .gimage import reconstruct

        rec = reconstruct(gi, frame="stored")
        pic = plot_mesh(rec, screenshot=None, off_screen=True if off_screen is None else off_screen,
                        window_size=window_size or (max(N, 128), max(N, 128)), view="xy")
        cv2 = lazy_import("cv2", "geometry-image montage")
        tiles.append(("surface", cv2.resize(pic, (N, N), interpolation=cv2.INTER_AREA)))
    if labels:
        tiles = [(name, _label(t, name)) for name, t in tiles]
    sep = np.full((N, gap, 3), 128, np.uint8)  # grey: a white mask tile stays visible
    parts = []
    for i, (_, t) in enumerate(tiles):
        if i:
            parts.append(sep)
        parts.append(t)
    img = np.ascontiguousarray(np.concatenate(parts, axis=1))
    if screenshot is not None:
        save_png(screenshot, img)
    return img


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    """Write a small label in the top-left corner (only on tiles large enough to read it):
    white text on a dark box, legible on any tile (a white mask, a saturated position image)."""
    N = tile.shape[0]
    if N < 96:
        return tile
    cv2 = lazy_import("cv2", "geometry-image montage")
    out = tile.copy()
    scale = N / 512.0
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale + 0.2, max(1, int(round(2 * scale)))
    (w, h), base = cv2.getTextSize(text, font, size, thick)
    pad = max(2, int(4 * scale))
    x0, y0 = pad, pad
    box = out[y0: y0 + h + base + 2 * pad, x0: x0 + w + 2 * pad].astype(np.float32)
    out[y0: y0 + h + base + 2 * pad, x0: x0 + w + 2 * pad] = (box * 0.25).astype(np.uint8)
    cv2.putText(out, text, (x0 + pad, y0 + pad + h), font, size, (255, 255, 255), thick, cv2.LINE_AA)
    return out


def compare_meshes(A, B, *, distance: bool = False, titles=("original", "reconstruction"), screenshot=None,
                   window_size=(1400, 700), off_screen=None, view: str = "front", up=None, clim=None) -> np.ndarray:
    """Two meshes side by side with linked cameras (e.g. original vs reconstruction).

    With ``distance=True`` each mesh is coloured by its distance to the other (same
    colour scale on both, in the meshes' units); otherwise textured / coloured as stored.
    ``view`` and ``up`` as in :func:`plot_mesh`; both cameras take ``A``'s frame.
    """
    off = _off_screen(off_screen, screenshot)
    pl = _plotter(off, window_size, shape=(1, 2))
    A_, B_ = unpack_mesh(A), unpack_mesh(B)
    frame = None
    if view not in AXIS_VIEWS:
        from .mesh.frame import mesh_frame

        frame = mesh_frame(A_[0], A_[1], up=up, face=getattr(A, "face_mask", None))
    dA = dB = None
    if distance:
        dA = distances(A_[0], B_[0], B_[1])
        dB = distances(B_[0], A_[0], A_[1])
        if clim is None:
            hi = float(max(np.quantile(dA, 0.98), np.quantile(dB, 0.98), 1e-12))
            clim = (0.0, hi)
    bar = {"title": "distance", "color": "black", "fmt": "%.2g", "n_labels": 3, "position_x": 0.2, "width": 0.6}
    for k, (m, d, title) in enumerate(((A, dA, titles[0]), (B, dB, titles[1]))):
        pl.subplot(0, k)
        if d is not None:
            _add_mesh(pl, m, scalars=d, cmap="viridis", clim=list(clim), scalar_bar_args=bar)
        else:
            _add_mesh(pl, m)
        if title:
            pl.add_text(str(title), font_size=12, color="black")
        _set_view(pl, view, frame=frame)
    pl.link_views()
    pl.subplot(0, 0)
    pl.reset_camera()
    return _finish(pl, screenshot, off)
