"""MP4s: frames and audio written and read back exactly (frame count, duration, streams), and
the turntables of `geoface view` for a mesh and for Gaussian splats."""
from __future__ import annotations

import wave

import numpy as np
import pytest

pytest.importorskip("imageio_ffmpeg", reason="videos need imageio-ffmpeg (pip install 'geoface[video]')")

from geoface import GeofaceError  # noqa: E402
from geoface.cli import main  # noqa: E402
from geoface.video import probe_video, write_video  # noqa: E402


def _wav(path, seconds=2.0, sr=16000):
    t = np.arange(int(sr * seconds)) / sr
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(sr)
        w.writeframes((0.3 * np.sin(2 * np.pi * 440 * t) * 32767).astype(np.int16).tobytes())


def test_frames_and_audio_round_trip(tmp_path):
    frames = [np.full((63, 81, 3), 4 * i, np.uint8) for i in range(40)]  # odd sides: padded by one pixel
    _wav(tmp_path / "a.wav", seconds=3.0)  # longer than the video: cut to it
    v = probe_video(write_video(frames, tmp_path / "v.mp4", fps=20, audio=tmp_path / "a.wav"))
    assert (v["frames"], v["fps"], v["width"], v["height"], v["codec"]) == (40, 20, 82, 64, "h264")
    assert abs(v["seconds"] - 2.0) < 1e-6 and v["audio"] and abs(v["duration"] - 2.0) < 0.1
    floats = [np.random.default_rng(0).random((32, 32, 3)) for _ in range(5)]  # float frames in [0, 1]
    v2 = probe_video(write_video(floats, tmp_path / "f.mp4", fps=5))
    assert v2["frames"] == 5 and not v2["audio"]
    with pytest.raises(GeofaceError, match="all be"):
        write_video([np.zeros((8, 8, 3)), np.zeros((8, 10, 3))], tmp_path / "x.mp4")
    with pytest.raises(GeofaceError, match=".mp4"):
        write_video(frames, tmp_path / "x.avi")
    assert not (tmp_path / "x.mp4").exists() and not list(tmp_path.glob(".x.*"))  # nothing half-written


def test_turntables_of_a_mesh_and_of_splats(tmp_path, capsys, monkeypatch):
    pytest.importorskip("pyvista")
    monkeypatch.setenv("GEOFACE_QUIET", "0")  # the command's own progress lines, as a user sees them
    from geoface.splat.gaussians import Gaussians
    from geoface.splat.ply import save_ply
    from geoface.synth.ict import ict_head, load_ict_model

    head = ict_head(load_ict_model(), seed=4)
    mesh = tmp_path / "head.obj"
    assert main(["synth", "ict", "-o", str(mesh), "--seed", "4", "-q"]) == 0
    out = tmp_path / "turn.mp4"
    capsys.readouterr()
    assert main(["view", str(mesh), "--turntable", str(out), "--seconds", "1", "--size", "64,48"]) == 0
    err = capsys.readouterr().err
    assert "turntable: frame 1/25" in err and "turntable: frame 25/25 (100%)" in err, err  # progress while it renders
    v = probe_video(out)
    assert (v["frames"], v["width"], v["height"]) == (25, 64, 48)
    assert main(["view", str(mesh), "--turntable", str(out), "--seconds", "1"]) == 2  # exists: never replaced
    g = Gaussians.from_mesh(head.V, head.F, np.tile([0.2, 0.7, 0.3], (len(head.V), 1)), opacity=0.9)
    ply = tmp_path / "head_gs.ply"
    save_ply(g, ply)
    assert main(["view", str(ply), "--turntable", str(tmp_path / "gs.mp4"), "--seconds", "0.5", "--size", "48,48"]) == 0
    assert probe_video(tmp_path / "gs.mp4")["frames"] == 12  # round(0.5 s x 25 fps)
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(tmp_path / "gs.mp4"))
    size = next(reader)["size"]
    first = np.frombuffer(next(reader), np.uint8).reshape(size[1], size[0], 3).astype(int)
    green = (first[..., 1] > first[..., 0] + 40) & (first[..., 1] > first[..., 2] + 40)
    assert green.mean() > 0.1  # the splats are drawn, in their colour, in the middle of the picture
    assert main(["view", str(ply), "--screenshot", str(tmp_path / "gs.png")]) == 2
    assert "Gaussian splats" in capsys.readouterr().err


def _frames(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    w, h = next(reader)["size"]
    return [np.frombuffer(f, np.uint8).reshape(h, w, 3).astype(int) for f in reader]


def _width(img) -> int:
    """Columns where the picture differs from its background (the top-left pixel)."""
    cols = (np.abs(img - img[0, 0]).sum(-1) > 40).any(0)
    return int(cols.sum())


def test_a_turntable_turns(tmp_path):
    """What the video shows: the frames change, a quarter turn shows the profile of a slab that
    is four times wider than deep (its silhouette about a quarter, or four times, as wide), half a
    turn the back (as wide as the front), and the last frame is nearly the first again."""
    pytest.importorskip("pyvista")
    import trimesh

    from geoface.mesh.io import save_mesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))  # wide along x, shallow along z
    path = tmp_path / "slab.obj"
    save_mesh(path, V=np.asarray(box.vertices), F=np.asarray(box.faces))
    out = tmp_path / "turn.mp4"
    assert main(["view", str(path), "--turntable", str(out), "--seconds", "0.64", "--size", "160,120", "--up", "+y"]) == 0
    fr = _frames(out)
    n = len(fr)
    assert n == 16
    w = [_width(f) for f in fr]
    assert np.abs(fr[n // 4] - fr[0]).mean() > 5, "the quarter-turn frame is the first one again"
    # the front the viewer picks on a box may be its wide or its narrow side: either way a quarter
    # turn changes the silhouette's width by about 4x (perspective and the 10° elevation aside)
    assert not 0.5 < w[n // 4] / w[0] < 2.0, f"no profile at a quarter turn: widths {w}"
    assert abs(w[n // 2] - w[0]) <= 0.15 * w[0], f"the back is not as wide as the front: widths {w}"
    assert w[-1] > 0.8 * w[0]


def test_a_turntable_shows_all_of_a_tall_figure(tmp_path):
    """A standing figure (a column four times taller than wide) stays whole in every frame: the
    top and bottom rows of the picture are background (at 2.6 radii it lost its head and feet)."""
    pytest.importorskip("pyvista")
    import trimesh

    from geoface.mesh.io import save_mesh

    col = trimesh.creation.box(extents=(0.5, 2.0, 0.3))
    path = tmp_path / "column.obj"
    save_mesh(path, V=np.asarray(col.vertices), F=np.asarray(col.faces))
    out = tmp_path / "turn.mp4"
    assert main(["view", str(path), "--turntable", str(out), "--seconds", "0.5", "--size", "96,96", "--up", "+y", "-q"]) == 0
    for f in _frames(out):
        fg = np.abs(f - f[0, 0]).sum(-1) > 40
        rows = np.flatnonzero(fg.any(1))
        assert len(rows) and rows.min() > 0 and rows.max() < f.shape[0] - 1, (rows.min(), rows.max())
        assert np.ptp(rows) > 0.5 * f.shape[0]  # and not a speck: it fills the picture's height
