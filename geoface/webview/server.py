"""The viser server behind ``geoface view --web`` (:mod:`geoface.webview`)."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from ..errors import GeofaceError
from .guard import check_host, check_port, guarded_serve, md_text, plain_text
from .items import (BOUNDARY_COLOR, GREY_COLOR, DEFAULT_PORT, boundary_segments, gimage_images, ViewItem, load_item,
                    import_trimesh, import_viser, glb_bytes, item_kind, uv_distortion_colors)

__all__ = ["WebView"]


def _label(name: str, limit: int = 60) -> str:
    """A file name as a one-line GUI label (viser shows labels as text; control characters and
    line breaks become spaces, and long names are shortened in the middle)."""
    s = plain_text(name)
    return s if len(s) <= limit else s[: limit // 2 - 1] + "…" + s[-(limit // 2 - 1):]


# ----------------------------------------------------------------------------- the server
#: strength of the image-based light (viser's default, 1.0, drew textures 1.25x too bright)
ENV_INTENSITY = 0.5



#: the share of the first view's width that the items may span (the middle, clear of the GUI panel)
VIEW_SPAN = 0.75

class WebView:
    """A viser server showing ``paths`` side by side (see the module's description).

    Parameters
    ----------
    paths : meshes, geometry-image folders, 3DGS PLY files, avatar model folders
    host, port : where the server listens (``127.0.0.1`` by default: this machine only)
    up : the up direction of the data ("+y" by default; "+z" for Z-up scans)
    drive : what drives an avatar: a WAV or a ``talk synth`` folder (talking avatars), a usage
        folder (headset removal)
    fps : frames per second of a talking avatar driven by a WAV
    """

    def __init__(self, paths, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, up=None, drive=None,
                 fps: float = 25.0, quiet: bool = False):
        from ..mesh.frame import parse_up

        paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        if not paths:
            raise GeofaceError("nothing to show: give at least one path")
        if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= int(port) <= 65535:
            raise GeofaceError(f"--port must be an integer in 0..65535; got {port!r}")
        host = check_host(host)
        port = check_port(host, int(port))
        self.up = parse_up(up)
        kinds = [item_kind(p) for p in paths]
        if drive is not None and "avatar" not in kinds:
            raise GeofaceError("--drive drives an avatar; none of the paths is an avatar model folder")
        self.items = [load_item(p, k, drive=drive, fps=fps) for p, k in zip(paths, kinds)]
        for it in self.items:
            it.extra["frame"] = self._frame_of(it)
        self.frame = self.items[0].extra["frame"]
        viser = import_viser()
        self._quiet = quiet
        with guarded_serve(host), self._hush():  # same-origin WebSocket handshakes only, Host naming this machine
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

    def _face_of(self, it: ViewItem):
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

    def _frame_of(self, it: ViewItem):
        from ..mesh.frame import mesh_frame, points_frame

        if it.F is None:  # splats: their centres
            return points_frame(it.V, up=self.up)
        return mesh_frame(it.V, it.F, up=self.up, face=self._face_of(it))

    # ---- the scene
    def _build(self):
        srv = self.server
        fr = self.frame
        srv.scene.set_up_direction(tuple(float(x) for x in fr.up))
        # light that shows a surface's colour as it is where it faces the camera (a texture's
        # colour within about 15% in brightness; tests/test_webview.py measures it)
        srv.scene.configure_environment_map(hdri="warehouse", environment_intensity=ENV_INTENSITY)
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
                f"- **{md_text(it.name)}** ({it.kind}" + ("" if it.extra["scale"] == 1 else f", shown ×{it.extra['scale']:.3g}") + ")"
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
        # the camera: in front, far enough that every item stands in the middle of a 16:9 window
        # clear of the GUI panel (which covers the right quarter of a 1280-pixel window): the
        # items span at most about half its width
        dist = 0.5 * depth + 1.05 * max(0.5 * span / (0.83 * VIEW_SPAN), 0.5 * height / np.tan(np.radians(25)))
        cam = srv.initial_camera
        cam.look_at = (0.0, 0.0, 0.0)
        cam.position = tuple(float(v) for v in fr.front * dist)
        cam.up = tuple(float(v) for v in fr.up)
        cam.near, cam.far = dist * 1e-3, dist * 20.0  # scans come in mm, m or anything else

    def _add_mesh(self, it: ViewItem, node: str, place: dict, k: int):
        srv = self.server
        m = it.extra["mesh"]
        has_tex = m.texture is not None and m.UV is not None
        modes = (["texture"] if has_tex else []) + (["colours"] if m.colors is not None else []) + ["plain"]
        if m.UV is not None:
            modes += ["UV distortion (QC)", "UV distortion (log area)"]
        handles: dict = {}
        with srv.gui.add_folder(f"{k + 1}. {_label(it.name)}"):
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
                from ..viz import texture_uint8, split_corner_uvs

                V2, F2, uv2, _ = split_corner_uvs(m.V, m.F, m.UV, m.FUV)
                tm = import_trimesh(V2, F2, uv=uv2, texture=texture_uint8(m.texture), flat=flat)
                handles["surface"] = srv.scene.add_glb(f"{node}/surface", glb_bytes(tm), **place)
            elif mode == "colours":
                tm = import_trimesh(m.V, m.F, vertex_colors=m.colors[:, :3], flat=flat)
                handles["surface"] = srv.scene.add_glb(f"{node}/surface", glb_bytes(tm), **place)
            elif mode.startswith("UV distortion"):
                metric = "qc" if "QC" in mode else "area"
                V2, F2, fc, (lo, hi) = uv_distortion_colors(m, metric)
                tm = import_trimesh(V2, F2, face_colors=fc)
                handles["surface"] = srv.scene.add_glb(f"{node}/surface", glb_bytes(tm), **place)
                legend.content = (f"{'QC ratio' if metric == 'qc' else 'log area ratio'}: "
                                  f"{lo:.2f} (dark) … {hi:.2f} (bright); flipped triangles magenta")
            else:
                handles["surface"] = srv.scene.add_mesh_simple(
                    f"{node}/surface", m.V.astype(np.float32), m.F.astype(np.uint32), color=GREY_COLOR,
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
                seg = boundary_segments(m.V, m.F)
                if len(seg):
                    handles["boundary"] = srv.scene.add_line_segments(
                        f"{node}/boundary", seg.astype(np.float32), BOUNDARY_COLOR, thickness=3.0,
                        thickness_units="screen", **place)

        colour.on_update(draw)
        shading.on_update(draw)
        wire.on_update(draw_wire)
        bnd.on_update(draw_boundary)
        draw()
        draw_boundary()

    def _add_gimage(self, it: ViewItem, node: str, place: dict, k: int):
        srv = self.server
        gi = it.extra["gi"]
        self._add_mesh(it, node, place, k)  # the surface it encodes
        tiles = gimage_images(gi, it.extra["folder"])
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
            # viser draws an image's first row at the bottom of this plane (its +y is up): give the
            # rows bottom first, so that the PNG's row 0 is at the top, as in the file
            img = np.ascontiguousarray(tiles[which.value][::-1])
            handle["img"] = srv.scene.add_image(f"{node}/image", img, size, size, format="png",
                                                wxyz=wxyz, position=tuple(float(v) for v in centre))

        which.on_update(draw)
        draw()

    def _add_splat(self, it: ViewItem, node: str, place: dict, k: int):
        g = it.extra["gaussians"]
        self._splats(node, g.means, g.log_scales, g.quats, g.opacity_logits, g.colors, place)
        with self.server.gui.add_folder(f"{k + 1}. {_label(it.name)}"):
            self.server.gui.add_markdown(f"{len(it.V):,} Gaussians")

    def _splats(self, node, means, log_scales, quats, opacity_logits, colors, place):
        import torch

        from ..splat.gaussians import SH_C0, covariance

        with torch.no_grad():
            cov = covariance(log_scales, quats).numpy()
            rgb = colors if colors.ndim == 2 else colors[:, 0, :] * SH_C0 + 0.5
            rgb = rgb.clamp(0, 1).numpy()
            op = torch.sigmoid(opacity_logits).numpy()[:, None]
        return self.server.scene.add_gaussian_splats(
            f"{node}/splats", means.detach().numpy().astype(np.float32), cov.astype(np.float32),
            rgb.astype(np.float32), op.astype(np.float32), **place)

    def _add_avatar(self, it: ViewItem, node: str, place: dict, k: int):
        srv = self.server
        drive = it.extra["drive"]
        T = drive.n_frames
        state = {"t": -1}
        handles: dict = {}
        with srv.gui.add_folder(f"{k + 1}. {_label(it.name)}"):
            slider = srv.gui.add_slider("frame", 0, max(T - 1, 1), 1, 0)
            play = srv.gui.add_checkbox("play", False)
            srv.gui.add_markdown(f"{T} frames at {drive.fps:g} fps, driven by {md_text(drive.what)}")
            video = None if drive.frames is None else srv.gui.add_image(drive.frames[0], label="the video's frame")

        def show(t: int):
            t = int(np.clip(t, 0, T - 1))
            if t == state["t"]:
                return
            g = drive.gaussians(t)
            old = handles.pop("splats", None)
            handles["splats"] = self._splats(node, g.means, g.log_scales, g.quats, g.opacity_logits, g.colors, place)
            if old is not None:
                old.remove()
            if video is not None:
                video.image = drive.frames[t]
            state["t"] = t

        slider.on_update(lambda _: show(slider.value))

        def player():
            while not self._stop.is_set():
                if play.value:
                    slider.value = (state["t"] + 1) % T  # on_update draws the frame
                time.sleep(1.0 / drive.fps)

        show(0)
        th = threading.Thread(target=player, daemon=True)
        th.start()
        self._players.append(th)

    # ---- running
    def html(self, dark_mode: bool = False) -> str:
        """The scene as one self-contained HTML page (viser's client and the scene's data inline):
        it opens from disk with no server, to turn the objects with the mouse; the avatar
        players and the GUI's switches stay with the live server."""
        with self._hush():
            return self.server.scene.as_html(dark_mode)

    def notebook(self, height: int = 480):
        """An inline, turnable 3D view for a Jupyter notebook: :meth:`html` in an ``<iframe>``
        (stored with the notebook, so it still turns where the notebook is read offline)."""
        import html as _html

        from IPython.display import HTML

        page = _html.escape(self.html(), quote=True)
        # in a <div>: IPython warns about a bare <iframe> (it suggests IFrame, which cannot hold a page inline)
        return HTML(f'<div><iframe srcdoc="{page}" style="width: 100%; height: {int(height)}px; border: 0"></iframe></div>')

    def serve(self, *, exit_after: float | None = None, idle_exit: float | None = None, poll: float = 0.2) -> None:
        """Serve until Ctrl-C, or ``exit_after`` seconds, or ``idle_exit`` seconds after the last
        browser has left (once one has come)."""
        import signal

        t0, last_seen = time.monotonic(), None
        previous = None
        if threading.current_thread() is threading.main_thread():  # SIGTERM stops it as Ctrl-C does
            def _term(signum, frame):
                raise KeyboardInterrupt

            previous = signal.signal(signal.SIGTERM, _term)
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
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)

    def _hush(self):
        """viser prints its banner and "Server stopped" with rich whatever ``verbose`` says: on
        stdout, or in a notebook as display output. Swallowed when quiet (the CLI prints the
        URL itself; a notebook's inline view has none to show)."""
        import contextlib
        import io

        if not self._quiet:
            return contextlib.nullcontext()

        @contextlib.contextmanager
        def hushed():
            import rich
            import rich.console

            sink = io.StringIO()
            saved = rich._console  # rich.print's global console (a notebook's displays through IPython)
            rich._console = rich.console.Console(file=sink, force_jupyter=False, force_terminal=False)
            try:
                with contextlib.redirect_stdout(sink):
                    yield
            finally:
                rich._console = saved

        return hushed()

    def stop(self) -> None:
        self._stop.set()
        with self._hush():
            self.server.stop()
            time.sleep(0.2)  # (the server thread says "stopped" as it ends)


