"""MP4 videos of rendered frames, with the driving audio: H.264 through imageio-ffmpeg, whose
wheel carries its own ffmpeg (``pip install 'geoface[video]'``; no system ffmpeg needed).

    from geoface.video import write_video, probe_video
    write_video(frames, "talk.mp4", fps=25, audio="speech.wav")    # frames: [T, H, W, 3]
    probe_video("talk.mp4")        # {'frames': 50, 'seconds': 2.0, 'fps': 25.0, 'audio': True, ...}

The file is written next to its destination and renamed into place when complete, so a
crash leaves no half-written video; frames of odd size are padded by one pixel (H.264 4:2:0
needs even sides).
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np

from ._io import default_mode
from ._lazy import lazy_import
from .errors import GeofaceError

__all__ = ["write_video", "probe_video", "ffmpeg_exe"]


def ffmpeg_exe() -> str:
    """The ffmpeg binary of imageio-ffmpeg."""
    return lazy_import("imageio_ffmpeg", "writing videos (pip install 'geoface[video]')").get_ffmpeg_exe()


def _to_uint8(img) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.round(np.clip(np.asarray(a, np.float32), 0, 1) * 255).astype(np.uint8)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise GeofaceError(f"video frames must be (H, W, 3) images; got shape {a.shape}")
    return a[..., :3]


def write_video(frames, path, *, fps: float = 25.0, audio=None, quality: float = 7.0) -> Path:
    """Write ``frames`` (an iterable of (H, W, 3) uint8 or float-in-[0, 1] images, all one size)
    to an MP4 at ``fps``; ``audio`` (a WAV or any file ffmpeg reads) is muxed as AAC and cut to
    the video's length. Returns the path."""
    iio = lazy_import("imageio_ffmpeg", "writing videos (pip install 'geoface[video]')")
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise GeofaceError(f"{path}: videos are written as .mp4")
    if not (0 < float(fps) <= 240):
        raise GeofaceError(f"fps must be in (0, 240]; got {fps}")
    if audio is not None and not Path(audio).is_file():
        raise GeofaceError(f"{audio}: no such audio file")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.mp4")
    writer = None
    n = 0
    try:
        for img in frames:
            a = _to_uint8(img)
            if writer is None:
                h, w = a.shape[:2]
                H, W = h + h % 2, w + w % 2
                out = ["-movflags", "+faststart"] + (["-shortest"] if audio is not None else [])
                writer = iio.write_frames(str(tmp), (W, H), fps=float(fps), codec="libx264", quality=quality,
                                          macro_block_size=1, output_params=out,
                                          audio_path=None if audio is None else str(audio),
                                          audio_codec=None if audio is None else "aac", ffmpeg_log_level="error")
                writer.send(None)
            if a.shape[:2] != (h, w):
                raise GeofaceError(f"video frames must all be {w}x{h}; frame {n} is {a.shape[1]}x{a.shape[0]}")
            if (H, W) != (h, w):
                a = np.pad(a, ((0, H - h), (0, W - w), (0, 0)), mode="edge")
            writer.send(np.ascontiguousarray(a))
            n += 1
        if writer is None:
            raise GeofaceError("no frames to write")
        writer.close()
        writer = None
        os.chmod(tmp, default_mode())
        os.replace(tmp, path)
    finally:
        if writer is not None:
            try:
                writer.close()
            except Exception:  # noqa: BLE001 — the real error is already on its way
                pass
        if tmp.exists():
            tmp.unlink()
    return path


def probe_video(path) -> dict:
    """Frame count, duration, frame rate, size and whether there is an audio stream (read by
    decoding the file with ffmpeg: exact, not the container's claim)."""
    path = Path(path)
    if not path.is_file():
        raise GeofaceError(f"{path}: no such video")
    iio = lazy_import("imageio_ffmpeg", "reading videos (pip install 'geoface[video]')")
    r = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True)
    info = r.stderr
    v = re.search(r"Stream #\S+.*Video: (\w+).*?, (\d+)x(\d+).*?, ([\d.]+) fps", info)
    if v is None:
        raise GeofaceError(f"{path}: no video stream")
    a = re.search(r"Stream #\S+.*Audio: (\w+)", info)
    frames, seconds = iio.count_frames_and_secs(str(path))
    d = re.search(r"Duration: (\d+):(\d+):([\d.]+)", info)
    duration = int(d.group(1)) * 3600 + int(d.group(2)) * 60 + float(d.group(3)) if d else float(seconds)
    return {"frames": int(frames), "seconds": float(seconds), "duration": duration, "fps": float(v.group(4)),
            "width": int(v.group(2)), "height": int(v.group(3)), "codec": v.group(1),
            "audio": a is not None, "audio_codec": a.group(1) if a else None}
