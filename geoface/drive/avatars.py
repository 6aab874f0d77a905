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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from geoface.splat.errors import SplatError

__all__ = ["AvatarDrive", "avatar_drive", "avatar_kind", "export_frames", "parse_frames", "splat_turntable"]


@dataclass
class AvatarDrive:
    """A trained avatar and what drives it: ``gaussians(t)`` for t in ``range(n_frames)``;
    ``frames`` (uint8 [T, H, W, 3]) are the video's own frames when there is a video."""

    n_frames: int
    fps: float
    what: str
    model_kind: str
    _gaussians: Callable
    frames: np.ndarray | None = None

    @torch.no_grad()
    def gaussians(self, t: int):
        if not 0 <= int(t) < self.n_frames:
            raise SplatError(f"frame {t} is outside 0..{self.n_frames - 1}")
        return self._gaussians(int(t))


def avatar_kind(model_dir) -> str:
    """"thgs" or "hfm" from the model folder's config.json (a SplatError otherwise)."""
    cfg = Path(model_dir) / "config.json"
    try:
        fmt = json.loads(cfg.read_text(encoding="utf-8")).get("format")
    except (OSError, ValueError, AttributeError):
        raise SplatError(f"{model_dir}: not a model folder (no readable config.json)") from None
    kinds = {"geoface-thgs": "thgs", "geoface-hfm-gs": "hfm"}
    if fmt not in kinds:
        raise SplatError(f"{model_dir}: not an avatar model (format {fmt!r}; expected a `talk train` or `hmd train` folder)")
    return kinds[fmt]


def _uint8(frames) -> np.ndarray:
    return np.round(np.clip(np.asarray(frames, np.float32), 0, 1) * 255).astype(np.uint8)


def avatar_drive(model_dir, source, *, fps: float = 25.0, model=None) -> AvatarDrive:
    """Load the avatar in ``model_dir`` (or use ``model``) and what drives it (``source``)."""
    kind = avatar_kind(model_dir)
    if source is None and kind == "thgs":  # the rest pose, silent, neutral: one frame
        from geoface.thgs.inference import load_thgs

        m = model or load_thgs(model_dir)
        J, K = len(m.template.joints), m.template.n_expr
        return AvatarDrive(1, float(fps), "nothing (the rest pose)", "thgs",
                           lambda t: m(np.zeros((J, 3)), np.zeros(3), np.zeros(K), m.audio_ref.clone()))
    if source is None:
        raise SplatError(f"{model_dir}: a headset-removal avatar is driven by a usage folder; give one")
    source = Path(source)
    if not source.exists():
        raise SplatError(f"{source}: no such file or folder to drive the avatar")
    if kind == "thgs":
        from geoface.thgs.inference import load_thgs

        return _thgs_drive(model or load_thgs(model_dir), source, fps)
    from geoface.hfm.io import load_hfm

    return _hfm_drive(model or load_hfm(model_dir), source)


def _thgs_drive(model, source: Path, fps: float) -> AvatarDrive:
    from geoface.avatar.audio import audio_features, read_wav

    J, K = len(model.template.joints), model.template.n_expr
    frames = None
    if source.is_dir():
        from geoface.thgs.data import load_talking

        data = load_talking(source)
        rot, transl, expr, audio = data.rot, data.transl, data.expr, data.audio
        frames, fps, what = _uint8(data.frames), float(data.fps), f"the video in {source.name}"
    elif source.suffix.lower() == ".wav":
        x, sr = read_wav(source)
        T = max(1, int(len(x) / sr * fps))
        audio = audio_features(source, T, fps)
        rot, transl, expr, what = np.zeros((T, J, 3)), np.zeros((T, 3)), np.zeros((T, K)), source.name
    else:
        raise SplatError(f"{source}: a talking avatar is driven by a WAV or a `talk synth` data folder")
    if audio.shape[1] != model.audio_dim:
        raise SplatError(f"{source}: {audio.shape[1]} audio features per frame; the model was trained on "
                         f"{model.audio_dim}")
    audio = model.audio_input(audio)

    def g(t):
        return model(rot[t], transl[t], expr[t], audio[t])

    return AvatarDrive(len(rot), float(fps), what, "thgs", g, frames)


def _hfm_drive(model, source: Path) -> AvatarDrive:
    from geoface.hfm.data import frame_input, load_video
    from geoface.hfm.train import frame_pose

    if not source.is_dir():
        raise SplatError(f"{source}: an HMD avatar is driven by a usage folder (`hmd synth` writes one)")
    video = load_video(source)
    boxes = video.boxes()
    meta = json.loads((source / "meta.json").read_text(encoding="utf-8"))

    def g(t):
        return model(*frame_input(video, t, model.cfg.crop, boxes), frame_pose(video, t))

    return AvatarDrive(len(video), float(meta.get("fps", 25.0)), f"the headset video in {source.name}", "hfm", g,
                       _uint8(video.frames))


def parse_frames(text: str | None, n_frames: int) -> list[int]:
    """``"12"``, ``"0:50"``, ``"0:50:5"`` (Python slice), ``"all"`` → frame indices in range."""
    if text is None or text == "all":
        return list(range(n_frames))
    try:
        parts = [None if p == "" else int(p) for p in text.split(":")]
    except ValueError:
        raise SplatError(f"--frames: a frame, a range A:B[:STEP] or 'all'; got {text!r}") from None
    if len(parts) == 1:
        if not 0 <= parts[0] < n_frames:
            raise SplatError(f"--frames: frame {parts[0]} is outside 0..{n_frames - 1}")
        return parts
    if len(parts) > 3 or (len(parts) == 3 and parts[2] is not None and parts[2] <= 0):
        raise SplatError(f"--frames: a frame, a range A:B[:STEP] or 'all'; got {text!r}")
    idx = list(range(n_frames))[slice(*parts)]
    if not idx:
        raise SplatError(f"--frames {text!r} selects none of the {n_frames} frames")
    return idx


def export_frames(drive: AvatarDrive, out, frames=None) -> list[Path]:
    """Write the Gaussians of ``frames`` (default: all) as 3DGS PLY files: ``out`` is a ``.ply``
    path for one frame, else a folder that gets ``frame_00000.ply``, ... Returns the paths."""
    from geoface.splat.gaussians import Gaussians
    from geoface.splat.ply import save_ply

    idx = list(range(drive.n_frames)) if frames is None else [int(t) for t in frames]
    if not idx:
        raise SplatError("no frames to export")
    out = Path(out)
    single = out.suffix.lower() == ".ply"
    if single and len(idx) != 1:
        raise SplatError(f"{out}: one .ply holds one frame; give a folder for {len(idx)} frames")
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
                    elevation: float = 10.0, background=(1.0, 1.0, 1.0)) -> int:
    """A turn around Gaussian splats (e.g. a 3DGS PLY), rendered by :func:`geoface.splat.rasterizer.rasterize`
    and written as an MP4 (``geoface.video``): from the front the splats' centres show
    (:func:`geoface.mesh.frame.points_frame`), ``elevation`` degrees above the horizon. Returns
    the frame count."""
    from geoface.mesh.frame import points_frame
    from geoface.camera import look_at
    from geoface.splat.rasterizer import rasterize
    from geoface.video import write_video

    means = gaussians.means.detach().double().numpy()
    fr = points_frame(means, up=up)
    n = max(2, int(round(float(seconds) * float(fps))))
    W, H = (int(x) for x in size)
    bg = torch.tensor(background, dtype=torch.float32)
    el = np.radians(elevation)

    def frames():
        for k in range(n):
            a = 2 * np.pi * k / n
            d = np.cos(el) * (np.cos(a) * fr.front + np.sin(a) * fr.right) + np.sin(el) * fr.up
            cam = look_at(fr.center + 2.4 * fr.radius * d, fr.center, fr.up, width=W, height=H, fov_y_deg=40.0)
            yield rasterize(gaussians, cam, background=bg)[0].clamp(0, 1).numpy()

    write_video(frames(), path, fps=fps)
    return n
