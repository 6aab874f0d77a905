"""geoface.viz and `geoface view`: off-screen pictures that show the right thing in the right place."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyvista", reason="geoface[viz] (pyvista) is not installed")

from geoface.cli import main  # noqa: E402
from geoface.mesh.io import Mesh, load_mesh, save_mesh  # noqa: E402
from geoface.synth import square_grid  # noqa: E402

_PROBE = textwrap.dedent(
    """
    import pyvista as pv
    pl = pv.Plotter(off_screen=True, window_size=[64, 64])
    pl.add_mesh(pv.Sphere(), color="red")
    img = pl.screenshot(return_img=True)
    pl.close()
    assert img.shape[:2] == (64, 64) and (img[..., 0] > 100).sum() > 100, "blank render"
    """
)


@pytest.fixture(scope="module", autouse=True)
def _offscreen_rendering():
    """Skip the module (with the reason) where VTK cannot render off-screen; a subprocess, so a crash stays there."""
    p = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
    if p.returncode != 0:
        tail = (p.stderr.strip().splitlines() or ["exit code %d" % p.returncode])[-1]
        pytest.skip(f"VTK cannot render off-screen on this machine (OSMesa/EGL/X missing?): {tail}")


BG = np.array([255, 255, 255])


def _object(img: np.ndarray) -> np.ndarray:
    """Pixels that differ from the white background."""
    return np.abs(img.astype(int) - BG).sum(axis=2) > 30


def _bbox(mask: np.ndarray):
    rows, cols = np.nonzero(mask)
    return rows.min(), rows.max(), cols.min(), cols.max()


def _rect(w=2.0, h=1.0, n=12):
    V, F = square_grid(n)
    V = V.astype(np.float64).copy()
    V[:, 0] = (V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0])
    V[:, 1] = (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])
    V[:, 2] = 0.0
    uv = V[:, :2].copy()
    V[:, 0] *= w
    V[:, 1] *= h
    return V, F, uv


def _red(img):
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (r > 120) & (g < 60) & (b < 60)


def _blue(img):
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (b > 120) & (r < 60) & (g < 60)


def _green(img):
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (g > 120) & (r < 60) & (b < 60)


def test_coloured_rectangle_lands_where_expected(tmp_path):
    from geoface import viz

    V, F, _ = _rect(2.0, 1.0)
    colors = np.where((V[:, 0] < 1.0)[:, None], [1.0, 0, 0], [0, 0, 1.0])  # left half red, right half blue
    out = tmp_path / "rect.png"
    img = viz.plot_mesh((V, F), colors=colors, screenshot=out, window_size=(200, 160))
    assert img.shape == (160, 200, 3) and img.dtype == np.uint8
    assert out.exists() and np.array_equal(viz_read(out), img)
    obj = _object(img)
    assert 0.15 < obj.mean() < 0.95  # a sizeable part of the picture is the object
    r0, r1, c0, c1 = _bbox(obj)
    assert abs((c0 + c1) / 2 - 100) < 10 and abs((r0 + r1) / 2 - 80) < 10  # centred
    assert 1.6 < (c1 - c0 + 1) / (r1 - r0 + 1) < 2.4  # a 2:1 rectangle stays 2:1 (x right, y up)
    red, blue = _red(img), _blue(img)
    assert red.sum() > 0.3 * obj.sum() and blue.sum() > 0.3 * obj.sum()
    assert np.nonzero(red)[1].mean() < 100 < np.nonzero(blue)[1].mean()  # red on the left, blue on the right


def viz_read(path):
    import cv2

    return cv2.imread(str(path), cv2.IMREAD_COLOR)[..., ::-1]


def _two_colour_texture(T=32):
    tex = np.zeros((T, T, 3), np.uint8)
    tex[: T // 2] = (0, 200, 0)  # top rows (v = 1) green
    tex[T // 2:] = (0, 0, 200)  # bottom rows (v = 0) blue
    return tex


def test_textured_mesh_with_per_corner_uvs_shows_the_texture():
    from geoface import viz

    V, F, uv = _rect(1.0, 1.0)
    # per-corner UVs (3 per face), as an OBJ with seams would have
    UV, FUV = uv[F.ravel()], np.arange(3 * len(F)).reshape(-1, 3)
    mesh = Mesh(V, F, UV=UV, FUV=FUV, texture=_two_colour_texture())
    img = viz.plot_mesh(mesh, window_size=(160, 160), off_screen=True)
    obj = _object(img)
    g, b = _green(img), _blue(img)
    assert g.sum() > 0.3 * obj.sum() and b.sum() > 0.3 * obj.sum()
    assert np.nonzero(g)[0].mean() < 80 < np.nonzero(b)[0].mean()  # v = 1 (green) at the top


def test_split_corner_uvs_one_vertex_per_distinct_pair():
    from geoface.viz import split_corner_uvs

    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = np.array([[0.0, 0], [1, 0], [1, 1], [0.5, 0.5], [0, 1]])
    FUV = np.array([[0, 1, 2], [3, 2, 4]])  # vertex 0 has two UVs (a seam)
    V2, F2, uv2, vmap = split_corner_uvs(V, F, UV, FUV)
    assert len(V2) == 5
    np.testing.assert_array_equal(V2[F2], V[F])
    np.testing.assert_array_equal(uv2[F2], UV[FUV])
    np.testing.assert_array_equal(V2, V[vmap])


def test_uv_distortion_colours_follow_the_stretch():
    from geoface import viz

    V, F, uv = _rect(1.0, 1.0)
    x = uv[:, 0]
    flat = viz.plot_uv_distortion(V, F, uv, window_size=(200, 200), off_screen=True)
    stretched = np.column_stack([x + 0.5 * x**2, uv[:, 1]])  # dx'/dx = 1 + x: QC from 1 (left) to 2 (right)
    img = viz.plot_uv_distortion(V, F, stretched, window_size=(200, 200), off_screen=True, clim=(1.0, 2.0))
    plot = img[:, :160]  # leave the colour bar out
    obj = _object(plot)
    assert obj.mean() > 0.2
    rows, cols = np.nonzero(obj)
    c0, c1 = cols.min(), cols.max()
    bright = plot.astype(int).sum(axis=2)
    left = bright[obj & (np.arange(160)[None, :] < c0 + (c1 - c0) * 0.2)].mean()
    right = bright[obj & (np.arange(160)[None, :] > c1 - (c1 - c0) * 0.2)].mean()
    assert right > left + 150  # viridis: dark purple (conformal) -> yellow (QC 2)
    # the identity map is conformal everywhere: one colour (viridis' lowest) across the plane
    fo = flat[:, :160][_object(flat[:, :160])].astype(int)
    assert np.median(np.abs(fo - [68, 1, 84]).sum(axis=1)) < 20
    with pytest.raises(Exception, match="metric"):
        viz.plot_uv_distortion(V, F, uv, metric="nope", off_screen=True)


@pytest.fixture(scope="module")
def small_gimage():
    from geoface.gimage import geometry_image

    V, F, uv = _rect(1.0, 1.0, n=16)
    V[:, 2] = 0.2 * np.sin(3 * V[:, 0])
    colors = np.column_stack([uv[:, 0], uv[:, 1], np.full(len(V), 0.5)])
    return geometry_image(V, F, uv, 32, colors=colors)


def test_gimage_montage_tiles_are_the_channels(small_gimage, tmp_path):
    from geoface import viz

    gi = small_gimage
    N, gap = 32, 4
    img = viz.gimage_montage(gi, gap=gap, screenshot=tmp_path / "m.png")
    assert img.shape == (N, 4 * N + 3 * gap, 3) and img.dtype == np.uint8
    assert (tmp_path / "m.png").exists()
    tiles = [img[:, k * (N + gap): k * (N + gap) + N] for k in range(4)]
    for k, name in enumerate(("position", "normal", "texture")):
        want = np.round(np.clip(gi.modality(name).transpose(1, 2, 0), 0, 1) * 255)
        assert np.abs(tiles[k].astype(int) - want).max() <= 1, name
    np.testing.assert_array_equal(tiles[3][..., 0] == 255, gi.mask)
    assert (img[:, N:N + gap] == 128).all()
    with_surface = viz.gimage_montage(gi, gap=gap, surface=True)
    assert with_surface.shape == (N, 5 * N + 4 * gap, 3)
    assert _object(with_surface[:, -N:]).mean() > 0.1  # the 3D surface tile shows the surface


def test_compare_meshes_side_by_side_with_distance():
    from geoface import viz

    V, F, _ = _rect(1.0, 1.0)
    B = V.copy()
    B[:, 2] += 0.05 * (V[:, 0] > 0.5)  # the right half moved away
    img = viz.compare_meshes((V, F), (B, F), distance=True, window_size=(320, 160), off_screen=True, titles=("", ""))
    assert img.shape == (160, 320, 3)
    left, right = _object(img[:, :160]), _object(img[:, 160:])
    assert left.mean() > 0.1 and right.mean() > 0.1  # both meshes are there, one per half
    # coloured by distance (viridis): on each mesh the moved half (x > 0.5, right) is brighter than the other
    for half in (img[:, :160], img[:, 160:]):
        obj = _object(half)
        cols = np.nonzero(obj)[1]
        mid = (cols.min() + cols.max()) / 2
        bright = half.astype(int).sum(axis=2)
        xs = np.arange(160)[None, :]
        assert bright[obj & (xs > mid + 10)].mean() > bright[obj & (xs < mid - 10)].mean() + 150
    plain = viz.compare_meshes((V, F), (V, F), window_size=(320, 160), off_screen=True)
    assert _object(plain[:, :160]).mean() > 0.1 and _object(plain[:, 160:]).mean() > 0.1


# --------------------------------------------------------------------------- geoface view
@pytest.fixture
def textured_obj(tmp_path):
    V, F, uv = _rect(1.0, 1.0)
    path = tmp_path / "quad.obj"
    save_mesh(path, Mesh.from_vertex_uv(V, F, uv, texture=_two_colour_texture()))
    return path


def test_cli_view_textured_mesh(textured_obj, tmp_path, capsys):
    assert load_mesh(textured_obj).texture is not None
    out = tmp_path / "shot.png"
    assert main(["view", str(textured_obj), "--screenshot", str(out), "--size", "240,180"]) == 0
    assert "textured mesh" in capsys.readouterr().out
    img = viz_read(out)
    assert img.shape == (180, 240, 3)
    assert _green(img).sum() > 1000 and _blue(img).sum() > 1000


def test_cli_view_uv_distortion(textured_obj, tmp_path):
    out = tmp_path / "uv.png"
    assert main(["view", str(textured_obj), "--uv-distortion", "--screenshot", str(out), "--size", "200,200"]) == 0
    assert _object(viz_read(out)).mean() > 0.2


def test_cli_view_gimage_folder(small_gimage, tmp_path):
    from geoface.gimage import save_gimage

    folder = save_gimage(tmp_path / "gi", small_gimage)
    out = tmp_path / "gi.png"
    assert main(["view", str(folder), "--screenshot", str(out), "--size", "64,64"]) == 0
    img = viz_read(out)
    assert img.shape == (64, 5 * 64 + 4 * 4, 3)  # position | normal | texture | mask | surface, 64-pixel tiles
    tex = img[:, 2 * 68: 2 * 68 + 64]
    want = np.round(small_gimage.modality("texture").transpose(1, 2, 0) * 255)
    assert np.abs(tex[::2, ::2].astype(int) - want).max() <= 1  # nearest-neighbour 2x of the texture


def test_cli_view_bad_input_one_line_exit_2(tmp_path, capsys, monkeypatch):
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    out = tmp_path / "never.png"
    assert main(["view", str(bad), "--screenshot", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("geoface: error:") and err.count("\n") == 1
    assert not out.exists()
    assert main(["view", str(tmp_path / "missing.ply"), "--screenshot", str(out)]) == 2
    assert main(["view", str(bad), "--screenshot", str(out), "--size", "big"]) == 2
    assert "--size" in capsys.readouterr().err
    assert not out.exists()
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert main(["view", str(bad)]) == 2
    assert "--screenshot" in capsys.readouterr().err


def test_off_screen_is_automatic(monkeypatch, tmp_path):
    from geoface import viz

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":0")
    assert viz.has_display() and not viz._off_screen(None, None)
    assert viz._off_screen(None, tmp_path / "a.png")  # a screenshot is always rendered off-screen
    assert viz._off_screen(True, None) and not viz._off_screen(False, tmp_path / "a.png")
    monkeypatch.delenv("DISPLAY")
    assert not viz.has_display() and viz._off_screen(None, None)
    with pytest.raises(Exception, match="screenshot"):
        viz.plot_mesh(_rect()[:2], off_screen=False)  # no window without a display: a clear error


def test_interactive_window_gives_back_its_last_frame(tmp_path):
    from geoface import viz

    class Window:  # stands in for a pyvista Plotter whose window the user closed
        def show(self):
            self.last_image = np.full((10, 12, 4), 7, np.uint8)

    img = viz._finish(Window(), tmp_path / "w.png", off_screen=False)
    assert img.shape == (10, 12, 3) and (img == 7).all()
    assert np.array_equal(viz_read(tmp_path / "w.png"), img)


def test_montage_labels_are_legible_on_every_tile(tmp_path):
    """Each tile's label is white text on a dark box: in the box most pixels are dark and some
    are white, on the saturated position tile and on the white mask tile alike; the caption
    of `view DIR --screenshot` names only the tiles that are there."""
    from geoface.gimage import load_gimage
    from geoface.viz import gimage_montage
    from tests.ddpm.conftest import make_gimage_dataset

    root = make_gimage_dataset(tmp_path / "gi", n_items=1, N=16)
    folder = root / "head_000" / "aug0"
    gi = load_gimage(folder)
    img = gimage_montage(gi, tile=256, gap=4)
    names = [m for m in ("position", "normal", "texture") if gi.has(m)] + ["mask"]
    assert img.shape[1] == len(names) * 256 + (len(names) - 1) * 4
    for k, name in enumerate(names):
        box = img[6:30, 4 + k * 260: 4 + k * 260 + 8 * len(name)].astype(int)
        dark = (box.max(-1) < 70).mean()
        white = (box.min(-1) > 200).mean()
        assert dark > 0.4 and white > 0.05, (name, dark, white)
    from geoface.cli import main

    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["view", str(folder), "--screenshot", str(tmp_path / "m.png")]) == 0
    caption = buf.getvalue()
    assert ("texture" in caption) == gi.has("texture") and "mask | surface" in caption


def test_the_surface_tile_shows_the_head_as_stored_upright_and_facing_us(tmp_path):
    """The montage's surface tile is the reconstruction in the stored frame seen from +z (it once
    re-oriented the mesh by itself, hiding a head stored sideways or face-up): an ICT head turned
    at random is converted, and the face detector finds its face in the tile, upright, with the
    eye line within 5° of level."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data_tools"))
    import make_stress_cases as S

    from geoface import viz
    from geoface.gimage import load_gimage
    from geoface.pipeline import ConvertOptions, convert
    from geoface.track.look import Looker

    def surface_face(case, out, **kw):
        convert(Mesh(case.V, case.F), out, ConvertOptions(res=128, reconstruct=False, preview=False, **kw), quiet=True)
        img = viz.gimage_montage(load_gimage(out), surface=True, labels=False, tile=256, window_size=(256, 256))
        with Looker(case.V, case.F) as look:
            d = look.detect(np.ascontiguousarray(img[:, -256:]))
        if d is None:
            return None
        eye_r, eye_l, nose, mouth = d[1][:4]
        return d[0], float(np.degrees(np.arctan2(-(eye_l[1] - eye_r[1]), eye_l[0] - eye_r[0]))), nose[1] < mouth[1]

    case = S.turned(S.ict_base(2), 41)
    score, tilt, nose_above_mouth = surface_face(case, tmp_path / "found")
    assert score > 0.7 and abs(tilt) < 5 and nose_above_mouth, (score, tilt)
    # stored with a wrong up (the face's right, given), the tile shows the head lying on its side
    wrong = surface_face(case, tmp_path / "wrong", up=tuple(float(x) for x in case.R @ np.array([1.0, 0.0, 0.0])))
    assert wrong is None or abs(wrong[1]) > 45, wrong
