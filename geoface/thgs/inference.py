"""A trained THGS avatar: saving and loading its model folder, rendering frames, and animating
it from speech alone (:func:`animate`)."""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians
from geoface.thgs.model import THGSConfig, THGSModel


def save_thgs(model: THGSModel, out_dir) -> None:
    from geoface.avatar.model_dir import write_model_dir

    out = write_model_dir(out_dir, model, {"format": THGSModel.FORMAT, "version": 1, "config": asdict(model.cfg),
                                           "audio_dim": int(model.audio_dim),
                                           "n_frames": int(model.d_rot.shape[0])})
    model.template.save(out / "template.npz")


def load_thgs(model_dir) -> THGSModel:
    from geoface.avatar.model_dir import load_model_state, read_model_config
    from geoface.avatar.template import Template

    from geoface.errors import ModelFolderError

    d, meta = read_model_config(model_dir, THGSModel.FORMAT, "THGS")
    cfg = THGSConfig.from_dict(meta["config"], where=f"{d}/config.json")
    for key in ("audio_dim", "n_frames"):
        if isinstance(meta.get(key), bool) or not isinstance(meta.get(key), int) or meta[key] < 0:
            raise ModelFolderError(f"{d}/config.json: {key} must be a non-negative integer; got {meta.get(key)!r}")
    sd = load_model_state(d / "model.safetensors")
    tpl = Template.load(d / "template.npz")
    try:
        g = Gaussians(sd["gaussians.means"], sd["gaussians.log_scales"], sd["gaussians.quats"],
                      sd["gaussians.opacity_logits"], sd["gaussians.colors"], sd["gaussians.parent"])
        model = THGSModel(tpl, cfg, int(meta["audio_dim"]), int(meta["n_frames"]), g)
        sd.setdefault("d_transl", torch.zeros_like(model.d_transl))  # saved before translation corrections
        sd.setdefault("tracked_joints", model.tracked_joints)  # ... and before the tracked masks
        sd.setdefault("tracked_expr", model.tracked_expr)
        model.load_state_dict(sd, strict=True)
    except (KeyError, RuntimeError) as e:
        raise AvatarError(f"{d}: weights do not match config.json ({str(e).splitlines()[0][:160]})") from None
    model.eval()
    model._dir = str(d)
    return model


@torch.no_grad()
def render_frames(model: THGSModel, camera, rot, transl, expr, audio, frames=None):
    """Render poses (and audio features) → ([T, H, W, 3] float32, per-frame seconds)."""
    from geoface.splat.rasterizer import rasterize

    out, times = [], []
    bg = torch.zeros(3)
    idx = range(len(rot)) if frames is None else frames
    audio = None if audio is None else model.audio_input(audio)
    for t in idx:
        t0 = time.perf_counter()
        gd = model(rot[t], transl[t], expr[t], None if audio is None else audio[t])
        out.append(rasterize(gd, camera, background=bg)[0].clamp(0, 1).numpy())
        times.append(time.perf_counter() - t0)
    return np.stack(out), np.asarray(times)


def animate(model: THGSModel, audio_path, out_dir=None, *, poses=None, fps: float = 25.0, camera=None):
    """Drive the avatar by speech (a WAV, or a .npy/.npz of per-frame features) and optional poses
    (.npz with rot/transl/expr; default: the rest pose, neutral expression). Writes
    ``out_dir/frames/*.png`` when given; returns (frames [T, H, W, 3], per-frame seconds)."""
    from geoface.avatar.audio import audio_features, read_wav
    from geoface.avatar.capture import camera_from_json, write_frame
    from geoface.thgs.data import load_poses

    p = Path(audio_path)
    if p.suffix.lower() == ".wav":
        x, sr = read_wav(p)
        T = max(1, int(len(x) / sr * fps))
    else:
        T = None
    J, K = len(model.template.joints), model.template.n_expr
    if poses is not None:
        rot, transl, expr = load_poses(poses, J, K)
        T = len(rot) if T is None else min(T, len(rot))
    elif T is None:
        raise AvatarError("with precomputed audio features give --poses (they fix the frame count)")
    A = audio_features(p, T, fps)
    if A.shape[1] != model.audio_dim:
        raise AvatarError(f"{p}: {A.shape[1]} audio features per frame; the model was trained on {model.audio_dim}")
    if poses is None:
        rot, transl, expr = np.zeros((T, J, 3)), np.zeros((T, 3)), np.zeros((T, K))
    if camera is None:
        cam_path = Path(getattr(model, "_dir", "")) / "camera.json"
        if not cam_path.is_file():
            raise AvatarError("no camera: the model folder has no camera.json")
        camera = camera_from_json(cam_path)
    frames, times = render_frames(model, camera, rot[:T], transl[:T], expr[:T], A)
    if out_dir is not None:
        for t, img in enumerate(frames):
            write_frame(out_dir, t, img)
    return frames, times


def drive_thgs(model: THGSModel, source, *, fps: float = 25.0):
    """:meth:`THGSModel.drive`: the avatar frame by frame, driven by a WAV (rest pose, neutral
    expression, the speech moves the mouth), a talking data folder (its tracked poses, expressions
    and speech, and its frames to compare with), or nothing (``None``: one frame at rest, silent)."""
    from geoface.avatar.audio import audio_features, read_wav
    from geoface.avatar.model_dir import AvatarDrive, uint8_frames

    J, K = len(model.template.joints), model.template.n_expr
    if source is None:
        return AvatarDrive(1, float(fps), "nothing (the rest pose)", model.KIND,
                           lambda t: model(np.zeros((J, 3)), np.zeros(3), np.zeros(K), model.audio_ref.clone()))
    source = Path(source)
    frames = None
    if source.is_dir():
        from geoface.thgs.data import load_talking

        data = load_talking(source)
        rot, transl, expr, audio = data.rot, data.transl, data.expr, data.audio
        frames, fps, what = uint8_frames(data.frames), float(data.fps), f"the video in {source.name}"
    elif source.suffix.lower() == ".wav":
        x, sr = read_wav(source)
        T = max(1, int(len(x) / sr * fps))
        audio = audio_features(source, T, fps)
        rot, transl, expr, what = np.zeros((T, J, 3)), np.zeros((T, 3)), np.zeros((T, K)), source.name
    else:
        raise AvatarError(f"{source}: a talking avatar is driven by a WAV or a talking data folder")
    if audio.shape[1] != model.audio_dim:
        raise AvatarError(f"{source}: {audio.shape[1]} audio features per frame; the model was trained on "
                          f"{model.audio_dim}")
    audio = model.audio_input(audio)

    def g(t):
        return model(rot[t], transl[t], expr[t], audio[t])

    return AvatarDrive(len(rot), float(fps), what, model.KIND, g, frames)

