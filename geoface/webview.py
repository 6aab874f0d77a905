"""Look at what geoface makes in a web browser: ``geoface view --web PATH [PATH ...]``.

A local `viser <https://viser.studio>`_ server shows, side by side in one scene (so one camera
moves them all, e.g. an original beside its reconstruction):

* **a mesh** (OBJ, PLY, OFF, STL, ...): its texture or vertex colours, or plain grey; smooth or
  flat shading; a wireframe; UV-distortion colouring (quasi-conformal ratio, log area ratio)
  when it has UVs; its boundary loops in red;
* **a geometry-image folder** (``geoface convert`` output): the surface it encodes, and beside it
  the images — position, normal, texture, mask, and the ROI when the folder has one;
* **a 3D Gaussian-splat PLY** (``geoface splat fit``, an avatar export): viser's splat renderer;
* **an avatar** (a ``geoface talk train`` model folder; drive it with ``--audio``, or with a
  ``talk synth`` data folder to see its frames beside the render): the animated splats, a frame
  slider and play / pause.

The camera starts in front of the first item (:func:`geoface.mesh.frame.mesh_frame`: a head
faces you whichever axis it was scanned along). The server listens on ``127.0.0.1`` unless told
otherwise; ``exit_after`` (seconds) or ``idle_exit`` (seconds after the last browser left) stop
it by themselves (scripts, tests).

Python::

    from geoface.webview import WebView
    view = WebView(["head.obj", "gimage/"], port=8080)
    print(view.url)
    view.serve()          # until Ctrl-C
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._lazy import lazy_import
from .errors import GeofaceError

__all__ = ["WebView", "item_kind", "DEFAULT_PORT"]

DEFAULT_PORT = 8080
_GREY = (204, 199, 189)
_BOUNDARY = (230, 40, 40)


def _viser():
    return lazy_import("viser", "geoface view --web (pip install 'geoface[web]')")


def item_kind(path) -> str:
    """What a path holds: "gimage", "splat", "avatar" or "mesh"."""
    p = Path(path)
    if not p.exists():
        raise GeofaceError(f"{p}: no such file or folder")
    if p.is_dir():
        if any((q / "meta.json").is_file() and (q / "position.png").is_file() for q in (p, p / "aug0")):
            return "gimage"
        if (p / "config.json").is_file() and (p / "template.npz").is_file():
            return "avatar"
        raise GeofaceError(f"{p}: a folder that is neither a geometry image (meta.json) nor an avatar model "
                           "(config.json + template.npz)")
    if p.suffix.lower() == ".ply":
        with open(p, "rb") as f:
            head = f.read(4096)
        if b"f_dc_0" in head and b"opacity" in head:
            return "splat"
    return "mesh"


# ----------------------------------------------------------------------------- items
@dataclass
class _Item:
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


def _load(path: Path, kind: str) -> _Item:
    if kind == "mesh":
        from .mesh.io import load_mesh

        m = load_mesh(path)
        return _Item(path, kind, m.V, m.F, path.name, {"mesh": m})
    if kind == "gimage":
        from .gimage import load_gimage, reconstruct

        folder = path if (path / "position.png").is_file() else path / "aug0"
        gi = load_gimage(folder)
        m = reconstruct(gi)
        return _Item(path, kind, m.V, m.F, path.name, {"mesh": m, "gi": gi, "folder": folder})
    if kind == "splat":
        from .splat.ply import load_ply

        g = load_ply(path)
        means = g.means.detach().numpy().astype(np.float64)
        return _Item(path, kind, means, None, path.name, {"gaussians": g})
    if kind == "avatar":
        from .splat.thgs import load_thgs

        model = load_thgs(path)
        return _Item(path, kind, model.V0.numpy().astype(np.float64), model.template.F, path.name, {"model": model})
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
    from .param.metrics import distortion
    from .viz import split_corner_uvs

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


def _trimesh(V, F, *, vertex_colors=None, face_colors=None, uv=None, texture=None, flat=False):
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

        tm.visual = trimesh.visual.TextureVisuals(uv=np.asarray(uv, np.float64), image=Image.fromarray(texture))
    elif vertex_colors is not None:
        c = np.asarray(vertex_colors)
        if c.dtype != np.uint8:
            c = np.round(np.clip(c, 0, 1) * 255).astype(np.uint8)
        tm.visual = trimesh.visual.ColorVisuals(tm, vertex_colors=c)
    return tm


def _texture8(T) -> np.ndarray:
    T = np.asarray(T)
    if T.dtype == np.uint16:
        T = (T // 257).astype(np.uint8)
    elif T.dtype != np.uint8:
        T = np.round(np.clip(T, 0, 1) * 255).astype(np.uint8)
    if T.ndim == 2:
        T = np.repeat(T[..., None], 3, axis=2)
    return np.ascontiguousarray(T[..., :3])


# ----------------------------------------------------------------------------- the server
class WebView:
    """A viser server showing ``paths`` side by side (see the module's description).

    Parameters
    ----------
    paths : meshes, geometry-image folders, 3DGS PLY files, avatar model folders
    host, port : where the server listens (``127.0.0.1`` by default: this machine only)
    up : the up direction of the data ("+y" by default; "+z" for Z-up scans)
    audio : a WAV, or a ``talk synth`` data folder, that drives an avatar
    fps : frames per second of an avatar's animation
    """

    def __init__(self, paths, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, up=None, audio=None,
                 fps: float = 25.0, quiet: bool = False):
        from .mesh.frame import mesh_frame, parse_up

        paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        if not paths:
            raise GeofaceError("nothing to show: give at least one path")
        if not 0 <= int(port) <= 65535:
            raise GeofaceError(f"--port must be in 0..65535; got {port}")
        self.up = parse_up(up)
        self.items = [_load(p, item_kind(p)) for p in paths]
        self.audio = None if audio is None else Path(audio)
        if self.audio is not None and not any(it.kind == "avatar" for it in self.items):
            raise GeofaceError("--audio drives an avatar; none of the paths is an avatar model folder")
        if any(it.kind == "avatar" for it in self.items) and self.audio is None:
            raise GeofaceError("an avatar needs something to say: --audio WAV (or a `talk synth` data folder)")
        self.fps = float(fps)
        for it in self.items:
            it.extra["frame"] = self._frame_of(it)
        self.frame = self.items[0].extra["frame"]
        viser = _viser()
        self.server = viser.ViserServer(host=host, port=int(port), verbose=not quiet)
        self._stop = threading.Event()
        self._players: list = []
        self._build()

    # ---- bookkeeping
    @property
    def url(self) -> str:
        host = self.server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "", None) else host
        return f"http://{host}:{self.server.get_port()}"

    def _face_of(self, it: _Item):
        meta = it.path.with_suffix(".json")
        if it.kind == "mesh" and meta.is_file():
            import json

            try:
                d = json.loads(meta.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                return None
            face = d.get("face_mask")
            if face and max(face) < len(it.V):
                return np.asarray(face, np.int64)
        return None

    def _frame_of(self, it: _Item):
        from .mesh.frame import mesh_frame, points_frame

        if it.F is None:  # splats: their centres
            return points_frame(it.V, up=self.up)
        return mesh_frame(it.V, it.F, up=self.up, face=self._face_of(it))

    # ---- the scene
    def _build(self):
        srv = self.server
        fr = self.frame
        srv.scene.set_up_direction(tuple(float(x) for x in fr.up))
        size0 = float(np.linalg.norm(self.items[0].hi - self.items[0].lo))
        B0 = np.column_stack([fr.right, fr.up, fr.front])
        for it in self.items:
            # a common scale: items over 3x larger or smaller than the first are shown at its size
            s = float(np.linalg.norm(it.hi - it.lo))
            it.extra["scale"] = 1.0 if s <= 0 or 1 / 3 <= s / size0 <= 3 else size0 / s
            # turned to face the same way as the first, when its own front differs by over 30 degrees
            f = it.extra["frame"]
            R = np.eye(3)
            if float(f.front @ fr.front) < np.cos(np.radians(30)):
                R = B0 @ np.column_stack([f.right, f.up, f.front]).T
            it.extra["rotation"] = R
            P = (it.V - (it.lo + it.hi) / 2) @ R.T * it.extra["scale"]
            it.extra["width"] = float(np.ptp(P @ fr.right))
            it.extra["height"] = float(np.ptp(P @ fr.up))
            it.extra["depth"] = float(np.ptp(P @ fr.front))
            it.extra["shift"] = 0.0
            if it.kind == "gimage":  # its images stand to the right of the surface, as tall as it
                it.extra["shift"] = -0.6 * it.extra["height"]
                it.extra["width"] += 1.2 * it.extra["height"]
        gap = 0.15 * max(it.extra["width"] for it in self.items)
        offsets = [0.0]
        for a, b in zip(self.items, self.items[1:]):  # side by side along the first item's "right"
            offsets.append(offsets[-1] + 0.5 * a.extra["width"] + gap + 0.5 * b.extra["width"])
        mid = (offsets[0] + offsets[-1]) / 2
        span = offsets[-1] - offsets[0] + 0.5 * (self.items[0].extra["width"] + self.items[-1].extra["width"])
        height = max(it.extra["height"] for it in self.items)
        depth = max(it.extra["depth"] for it in self.items)
        with srv.gui.add_folder("geoface"):
            srv.gui.add_markdown("\n".join(
                f"- **{it.name}** ({it.kind}" + ("" if it.extra["scale"] == 1 else f", shown ×{it.extra['scale']:.3g}") + ")"
                for it in self.items))
        from scipy.spatial.transform import Rotation

        for k, (it, off) in enumerate(zip(self.items, offsets)):
            R, sc = it.extra["rotation"], it.extra["scale"]
            target = fr.right * (off - mid + it.extra["shift"])  # where the item's centre goes
            pos = target - R @ ((it.lo + it.hi) / 2) * sc
            q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
            it.extra["centre"] = target
            place = {"position": tuple(float(v) for v in pos), "scale": float(sc),
                     "wxyz": (float(q[3]), float(q[0]), float(q[1]), float(q[2]))}
            getattr(self, f"_add_{it.kind}")(it, f"/item{k}", place, k)
        # the camera: in front, far enough to see every item in a 50-degree view
        dist = 0.5 * depth + 1.15 * max(0.5 * span / 0.62, 0.5 * height / np.tan(np.radians(25)))
        cam = srv.initial_camera
        cam.look_at = (0.0, 0.0, 0.0)
        cam.position = tuple(float(v) for v in fr.front * dist)
        cam.up = tuple(float(v) for v in fr.up)
        cam.near, cam.far = dist * 1e-3, dist * 20.0  # scans come in mm, m or anything else

    def _add_mesh(self, it: _Item, node: str, place: dict, k: int):
        srv = self.server
        m = it.extra["mesh"]
        has_tex = m.texture is not None and m.UV is not None
        modes = (["texture"] if has_tex else []) + (["colours"] if m.colors is not None else []) + ["plain"]
        if m.UV is not None:
            modes += ["UV distortion (QC)", "UV distortion (log area)"]
        handles: dict = {}
        with srv.gui.add_folder(f"{k + 1}. {it.name}"):
            colour = srv.gui.add_dropdown("colour", modes, initial_value=modes[0])
            shading = srv.gui.add_dropdown("shading", ["smooth", "flat"], initial_value="smooth")
            wire = srv.gui.add_checkbox("wireframe", False)
            bnd = srv.gui.add_checkbox("boundary loops", True)
            legend = srv.gui.add_markdown("")

        def draw(_=None):
            if "surface" in handles:
                handles.pop("surface").remove()
            flat = shading.value == "flat"
            mode = colour.value
            legend.content = ""
            if mode == "texture":
                from .viz import split_corner_uvs

                V2, F2, uv2, _ = split_corner_uvs(m.V, m.F, m.UV, m.FUV)
                tm = _trimesh(V2, F2, uv=uv2, texture=_texture8(m.texture), flat=flat)
                handles["surface"] = srv.scene.add_mesh_trimesh(f"{node}/surface", tm, **place)
            elif mode == "colours":
                tm = _trimesh(m.V, m.F, vertex_colors=m.colors[:, :3], flat=flat)
                handles["surface"] = srv.scene.add_mesh_trimesh(f"{node}/surface", tm, **place)
            elif mode.startswith("UV distortion"):
                metric = "qc" if "QC" in mode else "area"
                V2, F2, fc, (lo, hi) = uv_distortion_colors(m, metric)
                tm = _trimesh(V2, F2, face_colors=fc)
                handles["surface"] = srv.scene.add_mesh_trimesh(f"{node}/surface", tm, **place)
                legend.content = (f"{'QC ratio' if metric == 'qc' else 'log area ratio'}: "
                                  f"{lo:.2f} (dark) … {hi:.2f} (bright); flipped triangles magenta")
            else:
                handles["surface"] = srv.scene.add_mesh_simple(
                    f"{node}/surface", m.V.astype(np.float32), m.F.astype(np.uint32), color=_GREY,
                    flat_shading=flat, side="double", **place)

        def draw_wire(_=None):
            if "wire" in handles:
                handles.pop("wire").remove()
            if wire.value:
                handles["wire"] = srv.scene.add_mesh_simple(
                    f"{node}/wire", m.V.astype(np.float32), m.F.astype(np.uint32), color=(40, 40, 40),
                    wireframe=True, **place)

        def draw_boundary(_=None):
            if "boundary" in handles:
                handles.pop("boundary").remove()
            if bnd.value:
                seg = _boundary_segments(m.V, m.F)
                if len(seg):
                    handles["boundary"] = srv.scene.add_line_segments(
                        f"{node}/boundary", seg.astype(np.float32), _BOUNDARY, thickness=3.0,
                        thickness_units="screen", **place)

        colour.on_update(draw)
        shading.on_update(draw)
        wire.on_update(draw_wire)
        bnd.on_update(draw_boundary)
        draw()
        draw_boundary()

    def _add_gimage(self, it: _Item, node: str, place: dict, k: int):
        srv = self.server
        gi = it.extra["gi"]
        self._add_mesh(it, node, place, k)  # the surface it encodes
        tiles = _gimage_images(gi, it.extra["folder"])
        size = it.extra["height"]
        # the images stand to the right of the surface, facing the camera
        R = np.column_stack([self.frame.right, self.frame.up, self.frame.front])
        from scipy.spatial.transform import Rotation

        q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
        wxyz = (float(q[3]), float(q[0]), float(q[1]), float(q[2]))
        surface_width = it.extra["width"] - 1.2 * size
        centre = it.extra["centre"] + self.frame.right * (0.5 * surface_width + 0.1 * size + 0.5 * size)
        handle = {}
        with srv.gui.add_folder(f"{k + 1}. images"):
            which = srv.gui.add_dropdown("image", list(tiles), initial_value=next(iter(tiles)))

        def draw(_=None):
            if "img" in handle:
                handle.pop("img").remove()
            handle["img"] = srv.scene.add_image(f"{node}/image", tiles[which.value], size, size, format="png",
                                                wxyz=wxyz, position=tuple(float(v) for v in centre))

        which.on_update(draw)
        draw()

    def _add_splat(self, it: _Item, node: str, place: dict, k: int):
        g = it.extra["gaussians"]
        self._splats(node, g.means, g.log_scales, g.quats, g.opacity_logits, g.colors, place)
        with self.server.gui.add_folder(f"{k + 1}. {it.name}"):
            self.server.gui.add_markdown(f"{len(it.V):,} Gaussians")

    def _splats(self, node, means, log_scales, quats, opacity_logits, colors, place):
        import torch

        from .splat.gaussians import covariance

        with torch.no_grad():
            cov = covariance(log_scales, quats).numpy()
            rgb = colors if colors.ndim == 2 else colors[:, 0, :] * 0.28209479177387814 + 0.5
            rgb = rgb.clamp(0, 1).numpy()
            op = torch.sigmoid(opacity_logits).numpy()[:, None]
        return self.server.scene.add_gaussian_splats(
            f"{node}/splats", means.detach().numpy().astype(np.float32), cov.astype(np.float32),
            rgb.astype(np.float32), op.astype(np.float32), **place)

    def _add_avatar(self, it: _Item, node: str, place: dict, k: int):
        import torch

        srv = self.server
        model = it.extra["model"]
        drive = _avatar_drive(model, self.audio, self.fps)
        T = len(drive["rot"])
        state = {"t": 0}
        handles: dict = {}
        with srv.gui.add_folder(f"{k + 1}. {it.name}"):
            slider = srv.gui.add_slider("frame", 0, T - 1, 1, 0)
            play = srv.gui.add_checkbox("play", False)
            srv.gui.add_markdown(f"{T} frames at {self.fps:g} fps, driven by {drive['what']}")
            gt = srv.gui.add_image(drive["frames"][0], label="the video's frame") if drive["frames"] is not None else None

        def show(t: int):
            t = int(np.clip(t, 0, T - 1))
            with torch.no_grad():
                a = None if drive["audio"] is None else torch.as_tensor(drive["audio"][t])
                g = model(drive["rot"][t], drive["transl"][t], drive["expr"][t], a)
            old = handles.pop("splats", None)
            handles["splats"] = self._splats(node, g.means, g.log_scales, g.quats, g.opacity_logits, g.colors, place)
            if old is not None:
                old.remove()
            if gt is not None:
                gt.image = drive["frames"][t]
            state["t"] = t

        slider.on_update(lambda _: show(slider.value))

        def player():
            while not self._stop.is_set():
                if play.value:
                    slider.value = (state["t"] + 1) % T  # on_update draws the frame
                time.sleep(1.0 / self.fps)

        show(0)
        th = threading.Thread(target=player, daemon=True)
        th.start()
        self._players.append(th)

    # ---- running
    def serve(self, *, exit_after: float | None = None, idle_exit: float | None = None, poll: float = 0.2) -> None:
        """Serve until Ctrl-C, or ``exit_after`` seconds, or ``idle_exit`` seconds after the last
        browser has left (once one has come)."""
        t0, last_seen = time.monotonic(), None
        try:
            while True:
                now = time.monotonic()
                if self.server.get_clients():
                    last_seen = now
                if exit_after is not None and now - t0 >= exit_after:
                    break
                if idle_exit is not None and last_seen is not None and now - last_seen >= idle_exit:
                    break
                time.sleep(poll)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()


def _boundary_segments(V, F) -> np.ndarray:
    """(k, 2, 3) segments of every boundary edge (edges with one face)."""
    from .mesh.core import edge_topology

    et = edge_topology(np.asarray(F, np.int64))
    b = et.E[et.edge_faces == 1]
    return np.asarray(V, np.float64)[b]


def _gimage_images(gi, folder: Path) -> dict:
    """name → (N, N, 3) uint8 image of a geometry image's modalities, mask and ROI."""
    tiles = {}
    for name in ("position", "normal", "texture"):
        if gi.has(name):
            t = np.clip(gi.modality(name).transpose(1, 2, 0), 0, 1)
            tiles[name] = np.round(t * 255).astype(np.uint8)
    m = np.asarray(gi.mask, bool)
    tiles["mask"] = np.repeat((m * 255).astype(np.uint8)[..., None], 3, axis=2)
    roi = Path(folder) / "roi.png"
    if roi.is_file():
        import cv2

        r = cv2.imread(str(roi), cv2.IMREAD_GRAYSCALE)
        if r is not None and r.shape == m.shape:
            base = tiles.get("texture", tiles.get("normal", tiles["mask"])).astype(np.float32)
            over = base * 0.45 + np.array([255.0, 150.0, 40.0]) * 0.55 * (r[..., None] > 127)
            tiles["ROI"] = np.clip(np.where(r[..., None] > 127, over, base * 0.6), 0, 255).astype(np.uint8)
    return tiles


def _avatar_drive(model, source: Path, fps: float) -> dict:
    """Per-frame poses, expressions and audio features for an avatar: from a WAV (rest pose), or
    from a ``talk synth`` data folder (its tracked poses, its audio, its frames to compare)."""
    from .splat.audio import audio_features, read_wav

    J, K = len(model.template.joints), model.template.n_expr
    if source.is_dir():
        from .splat.thgs_data import load_talking

        data = load_talking(source)
        if data.audio.shape[1] != model.audio_ref.shape[0]:
            raise GeofaceError(f"{source}: {data.audio.shape[1]} audio features per frame; the model was trained "
                               f"on {model.audio_ref.shape[0]}")
        frames = np.round(np.clip(np.asarray(data.frames), 0, 1) * 255).astype(np.uint8)
        return {"rot": data.rot, "transl": data.transl, "expr": data.expr, "audio": data.audio, "frames": frames,
                "what": f"the video in {source.name}"}
    if source.suffix.lower() != ".wav":
        raise GeofaceError(f"--audio: a WAV file or a `talk synth` data folder; got {source}")
    x, sr = read_wav(source)
    T = max(1, int(len(x) / sr * fps))
    A = audio_features(source, T, fps)
    if A.shape[1] != model.audio_ref.shape[0]:
        raise GeofaceError(f"{source}: {A.shape[1]} audio features per frame; the model was trained on "
                           f"{model.audio_ref.shape[0]}")
    return {"rot": np.zeros((T, J, 3)), "transl": np.zeros((T, 3)), "expr": np.zeros((T, K)), "audio": A,
            "frames": None, "what": source.name}
