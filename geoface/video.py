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

import contextlib
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ._lazy import lazy_import
from .errors import GeofaceError

__all__ = ["write_video", "read_video", "iter_video", "video_rate", "probe_video", "ffmpeg_exe"]


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
    the video's length. Returns the path.

    The file appears complete or not at all: ffmpeg writes a temporary beside it that is renamed
    on success; a failure of ffmpeg (a full disk, a folder it may not write) is a one-line
    :class:`GeofaceError` with ffmpeg's own last message, and the temporary is removed (also one
    a killed run left behind, on the next run)."""
    from fractions import Fraction

    from ._io import atomic_path

    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise GeofaceError(f"{path}: videos are written as .mp4")
    if not (0.1 <= float(fps) <= 240):
        raise GeofaceError(f"fps must be in [0.1, 240]; got {fps}")
    if not (0 <= float(quality) <= 10):
        raise GeofaceError(f"quality must be in [0, 10]; got {quality}")
    if audio is not None and not Path(audio).is_file():
        raise GeofaceError(f"{audio}: no such audio file")
    exe = ffmpeg_exe()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise GeofaceError(f"{path.parent}: cannot create the folder ({e.strerror})") from None
    n = 0
    proc = err = None
    try:
        with atomic_path(path, suffix=".mp4") as tmp:
            err = tempfile.TemporaryFile()
            for img in frames:
                a = _to_uint8(img)
                if proc is None:
                    h, w = a.shape[:2]
                    H, W = h + h % 2, w + w % 2
                    rate = str(Fraction(float(fps)).limit_denominator(1001))
                    cmd = [exe, "-y", "-v", "error", "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{W}x{H}",
                           "-pix_fmt", "rgb24", "-r", rate, "-i", "-"]
                    cmd += ["-an"] if audio is None else ["-i", str(audio)]
                    cmd += ["-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(int((1 - quality / 10) * 51))]
                    if audio is not None:
                        cmd += ["-acodec", "aac", "-map", "0:v:0", "-map", "1:a:0", "-shortest"]
                    cmd += ["-movflags", "+faststart", "-f", "mp4", str(tmp)]
                    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=err)
                if a.shape[:2] != (h, w):
                    raise GeofaceError(f"video frames must all be {w}x{h}; frame {n} is {a.shape[1]}x{a.shape[0]}")
                if (H, W) != (h, w):
                    a = np.pad(a, ((0, H - h), (0, W - w), (0, 0)), mode="edge")
                try:
                    proc.stdin.write(np.ascontiguousarray(a).tobytes())
                except (BrokenPipeError, OSError):
                    break  # ffmpeg has stopped: its return code and message say why
                n += 1
            if proc is None:
                raise GeofaceError("no frames to write")
            with contextlib.suppress(OSError):
                proc.stdin.close()
            rc = proc.wait()
            if rc != 0:
                raise GeofaceError(f"{path}: ffmpeg failed ({_last_line(err) or f'exit code {rc}'})")
            if not tmp.is_file() or tmp.stat().st_size == 0:
                raise GeofaceError(f"{path}: ffmpeg wrote nothing")
    except OSError as e:  # the rename, the temporary, a full disk seen by Python
        raise GeofaceError(f"{path}: cannot write the video ({e.strerror or e})") from None
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if err is not None:
            err.close()
    return path


def _last_line(fh) -> str:
    """The last non-empty line ffmpeg wrote to ``fh`` (its error), shortened to one line."""
    try:
        fh.seek(0)
        text = fh.read()[-4000:].decode("utf-8", "replace")
    except OSError:
        return ""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""


def iter_video(path, *, max_frames: int = 100_000):
    """The frames of a video file one by one, ``(H, W, 3)`` uint8 RGB, decoded by the ffmpeg of
    imageio-ffmpeg (a clip longer than memory streams through). A file ffmpeg cannot read, or one
    of more than ``max_frames`` frames, is a one-line :class:`GeofaceError`."""
    path = Path(path)
    if not path.is_file():
        raise GeofaceError(f"{path}: no such video")
    iio = lazy_import("imageio_ffmpeg", "reading videos (pip install 'geoface[video]')")
    n = 0
    try:
        gen = iio.read_frames(str(path), pix_fmt="rgb24")
        meta = next(gen)
        w, h = (int(x) for x in meta["size"])
        for buf in gen:
            if n >= max_frames:
                gen.close()
                raise GeofaceError(f"{path}: more than {max_frames} frames")
            n += 1
            yield np.frombuffer(buf, np.uint8).reshape(h, w, 3)
    except (RuntimeError, OSError, StopIteration, KeyError, ValueError) as e:
        raise GeofaceError(f"{path}: not a video ffmpeg can read ({str(e).strip().splitlines()[-1][:200] if str(e).strip() else type(e).__name__})") from None
    if n == 0:
        raise GeofaceError(f"{path}: the video has no frames")


def video_rate(path) -> float:
    """Frames per second of a video file (its container's, as ffmpeg reports it; 25 when it gives none)."""
    iio = lazy_import("imageio_ffmpeg", "reading videos (pip install 'geoface[video]')")
    try:
        gen = iio.read_frames(str(path), pix_fmt="rgb24")
        meta = next(gen)
        gen.close()
    except (RuntimeError, OSError, StopIteration, KeyError, ValueError) as e:
        raise GeofaceError(f"{path}: not a video ffmpeg can read ({type(e).__name__})") from None
    return float(meta.get("fps") or 25.0)


def read_video(path, *, max_frames: int = 100_000) -> tuple[np.ndarray, float]:
    """(frames ``(T, H, W, 3)`` uint8 RGB, frames per second) of a video file (:func:`iter_video`)."""
    frames = list(iter_video(path, max_frames=max_frames))
    return np.stack(frames), video_rate(path)


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
