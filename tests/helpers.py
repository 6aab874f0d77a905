"""Helpers shared by the tests."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
_CANDIDATES = [
    os.environ.get("GEOFACE_SHARED_MESHES"),
    REPO.parent / "shared" / "data" / "meshes",  # the workplace's shared data
    REPO / "tests" / "data" / "meshes",  # vendored copies (see CREDITS.md there)
]
SHARED_MESHES = next(Path(p) for p in _CANDIDATES if p and (Path(p) / "spot.obj").is_file())
REAL_MESHES = ("beetle.obj", "spot.obj", "ninjaHead_Low.obj")


def shared_mesh(name: str) -> Path:
    path = SHARED_MESHES / name
    if not path.is_file():
        pytest.skip(f"shared mesh {path} not available (set GEOFACE_SHARED_MESHES)")
    return path


def angle_defects(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """2*pi minus the angle sum at every vertex (interior vertices only make sense)."""
    P = V[F]
    ang = np.zeros(F.shape)
    for k in range(3):
        u = P[:, (k + 1) % 3] - P[:, k]
        w = P[:, (k + 2) % 3] - P[:, k]
        ang[:, k] = np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), (u * w).sum(1))
    s = np.bincount(F.ravel(), weights=ang.ravel(), minlength=len(V))
    return 2 * np.pi - s


def planar_grid(n: int = 21):
    """``(F, uv, inner)``: an n×n grid of the unit square, counter-clockwise triangles, and the
    mask of its interior vertices."""
    from geoface.mesh.core import boundary_loops, signed_uv_areas
    from geoface.synth import square_grid

    V, F = square_grid(n)
    uv = V[:, :2].copy()
    if signed_uv_areas(F, uv).sum() < 0:
        F = F[:, ::-1].copy()
    inner = np.ones(len(uv), bool)
    inner[boundary_loops(F)[0]] = False
    return F, uv, inner


_VIDEO_DIRS = [os.environ.get("GEOFACE_SHARED_VIDEOS"), REPO.parent / "shared" / "data" / "videos"]


def shared_video(name: str) -> Path:
    """A real clip of ``../shared/data/videos`` (never copied into the repository: its terms keep
    it there); the test is skipped where the folder is absent."""
    for d in _VIDEO_DIRS:
        if d and (Path(d) / name).is_file():
            return Path(d) / name
    pytest.skip(f"shared video {name} not available (set GEOFACE_SHARED_VIDEOS)")


def short_clip(name: str, out: Path, seconds: float = 1.0) -> Path:
    """The first ``seconds`` of a shared clip, with its sound, as an MP4 in ``out``."""
    import subprocess

    from geoface.video import ffmpeg_exe

    src = shared_video(name)
    dst = Path(out) / f"{Path(name).stem}_{seconds:g}s.mp4"
    subprocess.run([ffmpeg_exe(), "-nostdin", "-v", "error", "-y", "-i", str(src), "-t", str(seconds), "-c:v", "libx264",
                    "-pix_fmt", "yuv420p", "-c:a", "aac", str(dst)], check=True)
    return dst


def white_headset(frames: np.ndarray, headset: np.ndarray) -> np.ndarray:
    """``frames`` (uint8) with the drawn headset (``geoface.avatar.protocol.HEADSET_RGB``, where
    ``headset`` holds) recoloured as white plastic (0.85 at its brightest), its shading kept."""
    from geoface.avatar.protocol import HEADSET_RGB

    out = frames.astype(np.float64)
    out[headset] *= 0.85 / max(HEADSET_RGB)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def geoface(*args, cwd=None) -> tuple[int, str, str]:
    """Run the ``geoface`` command (``--quiet``) in this process, as ``python -m geoface`` runs it:
    its exit code, stdout and stderr. A real process is kept for what only one shows (signals,
    a umask, the interpreter's own exit); everything else runs here, in a fraction of the time."""
    import contextlib
    import io

    from geoface.cli import main

    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(["--quiet", *map(str, args)])
            except SystemExit as e:  # what entry() would exit with
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    finally:
        os.chdir(here)
    return code, out.getvalue(), err.getvalue()
