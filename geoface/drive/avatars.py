"""Avatars frame by frame: what drives a trained model (speech, a tracked video, a headset
video), the Gaussians it gives at each frame, and their export as standard 3DGS PLY files.

* THGS (``geoface talk``): a WAV (rest pose, neutral expression, the speech moves the mouth),
  or a ``talk synth`` data folder (its tracked poses, expressions and speech, and its frames
  to compare with);
* HFM-GS (``geoface hmd``): a usage folder (``hmd synth`` writes one): the lower-face crop of
  each frame drives the whole head; its frames are shown beside.

    from geoface.drive.avatars import avatar_drive, export_frames
    drive = avatar_drive("talk_model/", "speech.wav")
    g = drive.gaussians(10)                       # GaussianTensors of frame 10, world space
    export_frames(drive, "frames_ply/", range(0, 50, 5))   # frame_00000.ply, ... (3DGS layout)
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from geoface.avatar.model_dir import AvatarDrive, AvatarModel
from geoface.errors import AvatarError

__all__ = ["AvatarDrive", "AvatarModel", "avatar_drive", "avatar_class", "avatar_formats", "avatar_kind",
           "export_frames", "parse_frames", "splat_turntable"]


def avatar_formats() -> dict[str, type[AvatarModel]]:
    """Every avatar model class by the ``format`` its ``config.json`` names."""
    from geoface.hfm.avatar import HFMAvatar
    from geoface.thgs.avatar import THGSAvatar

    return {cls.FORMAT: cls for cls in (HFMAvatar, THGSAvatar)}


def avatar_class(model_dir) -> type[AvatarModel]:
    """The model class of the folder ``model_dir`` (its config.json's ``format``)."""
    cfg = Path(model_dir) / "config.json"
    try:
        fmt = json.loads(cfg.read_text(encoding="utf-8")).get("format")
    except (OSError, ValueError, AttributeError):
        raise AvatarError(f"{model_dir}: not a model folder (no readable config.json)") from None
    formats = avatar_formats()
    if fmt not in formats:
        raise AvatarError(f"{model_dir}: not an avatar model (format {fmt!r}; expected one of {sorted(formats)}: a "
                          "`talk train` or `hmd train` folder)")
    return formats[fmt]


def avatar_kind(model_dir) -> str:
    """The avatar's ``KIND`` ("thgs" or "hfm") from the model folder's config.json."""
    return avatar_class(model_dir).KIND


def avatar_drive(model_dir, source, *, fps: float = 25.0, model=None) -> AvatarDrive:
    """Load the avatar in ``model_dir`` (or use ``model``, a loaded network of its kind) and what
    drives it (``source``; None: the rest pose, where the avatar has one)."""
    cls = avatar_class(model_dir)
    model = cls(model) if model is not None else cls.load(model_dir)
    if source is not None and not Path(source).exists():
        raise AvatarError(f"{source}: no such file or folder to drive the avatar")
    return model.drive(None if source is None else Path(source), fps=fps)


def parse_frames(text: str | None, n_frames: int) -> list[int]:
    """``"12"``, ``"0:50"``, ``"0:50:5"`` (Python slice), ``"all"`` → frame indices in range."""
    if text is None or text == "all":
        return list(range(n_frames))
    try:
        parts = [None if p == "" else int(p) for p in text.split(":")]
    except ValueError:
        raise AvatarError(f"--frames: a frame, a range A:B[:STEP] or 'all'; got {text!r}") from None
    if len(parts) == 1:
        if not 0 <= parts[0] < n_frames:
            raise AvatarError(f"--frames: frame {parts[0]} is outside 0..{n_frames - 1}")
        return parts
    if len(parts) > 3 or (len(parts) == 3 and parts[2] is not None and parts[2] <= 0):
        raise AvatarError(f"--frames: a frame, a range A:B[:STEP] or 'all'; got {text!r}")
    idx = list(range(n_frames))[slice(*parts)]
    if not idx:
        raise AvatarError(f"--frames {text!r} selects none of the {n_frames} frames")
    return idx


def export_frames(drive: AvatarDrive, out, frames=None) -> list[Path]:
    """Write the Gaussians of ``frames`` (default: all) as 3DGS PLY files: ``out`` is a ``.ply``
    path for one frame, else a folder that gets ``frame_00000.ply``, ... Returns the paths."""
    from geoface.splat.gaussians import Gaussians
    from geoface.splat.ply import save_ply

    idx = list(range(drive.n_frames)) if frames is None else [int(t) for t in frames]
    if not idx:
        raise AvatarError("no frames to export")
    out = Path(out)
    single = out.suffix.lower() == ".ply"
    if single and len(idx) != 1:
        raise AvatarError(f"{out}: one .ply holds one frame; give a folder for {len(idx)} frames")
    paths = []
    for t in idx:
        gt = drive.gaussians(t)
        g = Gaussians(gt.means.detach(), gt.log_scales.detach(), gt.quats.detach(), gt.opacity_logits.detach(),
                      gt.colors.detach())
        p = out if single else out / f"frame_{t:05d}.ply"
        p.parent.mkdir(parents=True, exist_ok=True)
        save_ply(g, p)
        paths.append(p)
    return paths


@torch.no_grad()
def splat_turntable(gaussians, path, *, seconds: float = 6.0, fps: float = 25.0, size=(512, 512), up=None,
                    elevation: float = 10.0, background=(1.0, 1.0, 1.0), quiet: bool | None = None) -> int:
    """A turn around Gaussian splats (e.g. a 3DGS PLY), rendered by :func:`geoface.splat.rasterizer.rasterize`
    and written as an MP4 (``geoface.video``): from the front the splats' centres show
    (:func:`geoface.mesh.frame.points_frame`), ``elevation`` degrees above the horizon. Returns
    the frame count."""
    from geoface.mesh.frame import points_frame
    from geoface.camera import look_at
    from geoface.splat.rasterizer import rasterize
    from geoface.progress import progress
    from geoface.video import write_video

    means = gaussians.means.detach().double().numpy()
    fr = points_frame(means, up=up)
    n = max(2, int(round(float(seconds) * float(fps))))
    W, H = (int(x) for x in size)
    bg = torch.tensor(background, dtype=torch.float32)
    el = np.radians(elevation)

    def frames():
        for k in progress(range(n), "turntable", unit="frames", quiet=quiet):
            a = 2 * np.pi * k / n
            d = np.cos(el) * (np.cos(a) * fr.front + np.sin(a) * fr.right) + np.sin(el) * fr.up
            cam = look_at(fr.center + 2.4 * fr.radius * d, fr.center, fr.up, width=W, height=H, fov_y_deg=40.0)
            yield rasterize(gaussians, cam, background=bg)[0].clamp(0, 1).numpy()

    write_video(frames(), path, fps=fps)
    return n
