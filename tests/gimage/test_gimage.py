"""Geometry images: rasterization, 16-bit IO, reconstruction, the convert pipeline."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geoface.errors import InvalidGeometryImageError
from geoface.gimage import geometry_image, load_gimage, pixel_uv, rasterize_faces, reconstruct, save_gimage
from geoface.gimage.raster import pixel_grid_uv
from geoface.gimage.image import Q
from geoface.synth import irregular_flat_patch, spherical_cap, square_grid


def test_rasterize_covers_every_pixel_once_with_exact_barycentrics():
    V, F = irregular_flat_patch(300, seed=1)
    uv = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], 0)
    N = 64
    for align in (False, True):
        face, bary = rasterize_faces(F, uv, N, align_corners=align)
        assert np.allclose(bary[face >= 0].sum(1), 1.0)
        # barycentric interpolation of the UVs themselves gives back the pixels' sample points
        ok = face >= 0
        rec = (uv[F[face[ok]]] * bary[ok][:, :, None]).sum(1)
        assert np.abs(rec - pixel_grid_uv(N, align)[ok]).max() < 1e-12
        # the patch's convex hull is the square minus the hull gaps: coverage is high
        assert ok.mean() > 0.9
    assert np.array_equal(pixel_grid_uv(N, False), pixel_uv(N))


def test_aligned_grid_samples_the_square_edges():
    """Geometry images (format 2) sample the square's edges: a map that fills the square
    covers every pixel, and the outer ring of pixels is the mesh boundary."""
    V, F = square_grid(7)
    N = 16
    gi = geometry_image(V, F, V[:, :2], N)
    assert gi.meta["version"] == 2 and gi.align_corners and gi.mask.all()
    P = gi.positions()
    assert np.allclose(P[0, :, 1], 1.0) and np.allclose(P[-1, :, 1], 0.0)  # top and bottom rows: y = 1, 0
    assert np.allclose(P[:, 0, 0], 0.0) and np.allclose(P[:, -1, 0], 1.0)
    assert np.abs(P[:, :, :2] - gi.sample_uv()).max() < 1e-6


def test_flat_square_round_trips_exactly():
    V, F = square_grid(9)  # the unit square in z = 0
    N = 32
    gi = geometry_image(V, F, V[:, :2], N)
    assert gi.mask.all()
    mesh = reconstruct(gi)
    assert len(mesh.V) == N * N and len(mesh.F) == 2 * (N - 1) ** 2
    # every vertex sits exactly where the surface maps its pixel (one quantisation step)
    step = 1.0 / Q
    j, i = np.round(mesh.UV[:, 0] * N - 0.5).astype(int), np.round((1 - mesh.UV[:, 1]) * N - 0.5).astype(int)
    assert np.abs(mesh.V[:, :2] - gi.sample_uv()[i, j]).max() <= step
    # the boundary is sampled: the reconstruction spans the whole square
    assert np.allclose(mesh.V[:, :2].min(0), 0, atol=step) and np.allclose(mesh.V[:, :2].max(0), 1, atol=step)
    assert np.abs(mesh.V[:, 2]).max() <= 1e-12
    # orientation preserved: normals still +z
    from geoface.mesh.core import face_normals

    assert (face_normals(mesh.V, mesh.F)[:, 2] > 0).all()


def test_format_1_folders_still_load_with_pixel_centres(tmp_path):
    """Folders written before the aligned grid (format 1: no ``align_corners``) load, and say
    their pixels sample UV ((j + 0.5) / N, ...)."""
    V, F = square_grid(5)
    gi = geometry_image(V, F, V[:, :2], 16)
    save_gimage(tmp_path / "gi", gi)
    meta = json.loads((tmp_path / "gi" / "meta.json").read_text())
    meta["version"] = 1
    del meta["align_corners"]
    (tmp_path / "gi" / "meta.json").write_text(json.dumps(meta))
    old = load_gimage(tmp_path / "gi")
    assert not old.align_corners
    assert np.allclose(old.sample_uv(), pixel_uv(16))
    assert reconstruct(old).V.shape[0] == 16 * 16
    meta["version"] = 3
    (tmp_path / "gi" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(InvalidGeometryImageError, match="newer"):
        load_gimage(tmp_path / "gi")


def test_png16_round_trip_within_one_step(tmp_path):
    V, F = spherical_cap(1.0, np.pi / 3, 10)
    uv = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], 0)
    rng = np.random.default_rng(0)
    colors = rng.random((len(V), 3))
    gi = geometry_image(V, F, uv, 48, colors=colors)
    save_gimage(tmp_path / "gi", gi)
    back = load_gimage(tmp_path / "gi")
    assert back.image.shape == gi.image.shape and back.channels == gi.channels
    assert np.abs(back.image - gi.image).max() <= 0.5 / Q + 1e-7
    assert (back.mask == gi.mask).all()
    assert back.meta["bbox_min"] == gi.meta["bbox_min"]


def test_load_rejects_bad_folders(tmp_path):
    import cv2

    V, F = square_grid(4)
    gi = geometry_image(V, F, V[:, :2], 16)
    d = tmp_path / "gi"
    save_gimage(d, gi)
    (d / "position.png").write_bytes(b"not a png")
    with pytest.raises(InvalidGeometryImageError, match="not a readable PNG"):
        load_gimage(d)
    save_gimage(d, gi)
    cv2.imwrite(str(d / "normal.png"), np.zeros((16, 16, 3), np.uint8))  # 8-bit
    with pytest.raises(InvalidGeometryImageError, match="16-bit"):
        load_gimage(d)
    save_gimage(d, gi)
    cv2.imwrite(str(d / "position.png"), np.zeros((8, 8, 3), np.uint16))  # wrong size
    with pytest.raises(InvalidGeometryImageError, match="16x16"):
        load_gimage(d)
    save_gimage(d, gi)
    meta = json.loads((d / "meta.json").read_text())
    del meta["bbox_max"]
    (d / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(InvalidGeometryImageError, match="bbox_max"):
        load_gimage(d)
    with pytest.raises(InvalidGeometryImageError):
        load_gimage(tmp_path / "missing")


def test_bad_resolution_and_uv():
    V, F = square_grid(4)
    with pytest.raises(InvalidGeometryImageError):
        geometry_image(V, F, V[:, :2], 1)
    with pytest.raises(InvalidGeometryImageError):
        geometry_image(V, F, np.full((len(V), 2), np.nan), 8)


def test_texture_sampled_through_corner_uvs():
    V, F = square_grid(6)
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:, 32:, 0] = 255  # right half red
    gi = geometry_image(V, F, V[:, :2], 32, texture=tex, tex_uv=V[:, :2], tex_fuv=F)
    t = gi.modality("texture")
    assert t[0, :, :14].max() == 0 and t[0, :, 18:].min() == 1.0


@pytest.fixture(scope="module")
def cap_pipeline():
    from geoface.param.measure import measure_preserving_map
    from geoface.param.ricci import ricci_flow_rectangle

    V, F = spherical_cap(1.0, np.pi / 3, 30)
    r = ricci_flow_rectangle(V, F)
    m = measure_preserving_map(V, r.F, r.unit_square(), lam=1.0)
    return V, r.F, r.unit_square(), m.uv


@pytest.mark.parametrize("which", ["conformal", "measure"])
def test_spherical_cap_round_trip_hausdorff(cap_pipeline, which):
    from geoface.pipeline import reconstruction_error

    V, F, uv_c, uv_m = cap_pipeline
    gi = geometry_image(V, F, uv_m if which == "measure" else uv_c, 256)
    rec = reconstruct(gi)
    err = reconstruction_error(V, F, rec.V, rec.F)
    assert err["hausdorff"] <= 0.005, err
    assert err["mean"] <= 0.001


def test_convert_cli_end_to_end(tmp_path, capsys):
    from geoface.cli import main

    head = tmp_path / "head.obj"
    assert main(["synth", "head", "-o", str(head), "--vertices", "3000", "--meta", str(tmp_path / "head.json"), "-q"]) == 0
    out = tmp_path / "out"
    assert main(["convert", str(head), "-o", str(out), "--res", "64", "--roi", str(tmp_path / "head.json"), "--augment", "2", "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert len(m["sets"]) == 2
    for k, st in enumerate(m["sets"]):
        d = out / f"aug{k}"
        for f in ("position.png", "normal.png", "texture.png", "mask.png", "meta.json", "preview.png", "reconstruction.obj"):
            assert (d / f).is_file(), f
        assert st["distortion"]["flipped"] == 0
        assert st["roi_pixel_share"] > 0.3  # the face (~20% of the area) magnified by 2.5
        import cv2

        roi = cv2.imread(str(d / "roi.png"), cv2.IMREAD_GRAYSCALE)  # the same share, as an image
        mask = cv2.imread(str(d / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
        assert roi.shape == (64, 64) and set(np.unique(roi)) <= {0, 255}
        assert abs((roi[mask] > 127).mean() - st["roi_pixel_share"]) < 1e-9
        assert st["reconstruction"]["hausdorff"] < 0.08
    gi = load_gimage(out / "aug1")
    assert gi.meta["corners"] != load_gimage(out / "aug0").meta["corners"]
    rec = tmp_path / "rec.obj"
    assert main(["reconstruct", str(out / "aug0"), "-o", str(rec), "-q"]) == 0
    assert rec.is_file() and (tmp_path / "rec_normal.png").is_file()
    mtl = (tmp_path / "rec.mtl").read_text()
    keys = {line.split()[0].lower() for line in mtl.splitlines() if line.strip() and not line.startswith("#")}
    assert not keys & {"map_bump", "bump", "norm", "map_kn"}, mtl  # not a tangent-space / bump map
    assert "# rec_normal.png: object-space normal map" in mtl


def test_convert_bad_input_leaves_no_output(tmp_path, capsys):
    from geoface.cli import main

    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    out = tmp_path / "out"
    assert main(["convert", str(bad), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("geoface: error:")
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["bad.obj"]
    assert main(["convert", str(bad), "-o", str(out), "--roi", str(tmp_path / "nope.npy")]) == 2
    assert main(["reconstruct", str(tmp_path), "-o", str(tmp_path / "r.obj")]) == 2
    assert not (tmp_path / "r.obj").exists()
