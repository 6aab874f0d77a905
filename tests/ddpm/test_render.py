"""Renders for evaluation: fixed cameras and lights, shaded in grey, deterministic."""
import numpy as np
import pytest

pytest.importorskip("pyvista")

from geoface import GeofaceError
from geoface.ddpm.render import HeadRenderer, grid_image, similarity_align
from geoface.synth.surfaces import sphere


def test_fixed_cameras_see_sizes_and_the_same_picture_twice():
    V, F = sphere(1.0, 3)
    V = np.asarray(V, np.float64)
    with HeadRenderer(center=(0, 0, 0), scale=2.0, size=64, views=("front", "side")) as r:
        a = r.render(V, F)
        b = r.render(V, F)
        small = r.render(0.5 * V, F)
        shifted = r.render(V + [0.8, 0, 0], F)
    assert a.shape == (2, 64, 64) and a.dtype == np.float32 and 0 <= a.min() and a.max() <= 1
    assert np.array_equal(a, b)  # deterministic
    cover = (a[0] > 0.02).mean()
    # the camera frames a sphere of radius `scale`: a unit sphere fills (1/2)^2 of its disc,
    # half the radius a quarter of that
    assert cover == pytest.approx(np.pi / 4 * 0.25 * 1.0, rel=0.15)
    assert (small[0] > 0.02).mean() == pytest.approx(cover / 4, rel=0.2)
    # the camera does not follow the mesh: a shifted sphere moves in the front view (to the
    # right: +x) and not in the side view's horizontal direction
    cols = lambda img: np.average(np.arange(64), weights=(img > 0.02).sum(0))  # noqa: E731
    assert cols(shifted[0]) - cols(a[0]) > 5 and abs(cols(shifted[1]) - cols(a[1])) < 2
    # the lights are fixed in the scene, not on the camera: the side view sees another shading
    # of the same sphere than the front view
    assert not np.allclose(a[0], a[1])


def test_renderer_rejects_bad_input():
    with pytest.raises(GeofaceError, match="views"):
        HeadRenderer(views=("top-down",))
    with pytest.raises(GeofaceError, match="scale"):
        HeadRenderer(scale=0.0)
    r = HeadRenderer(size=16)
    with pytest.raises(GeofaceError, match="finite"):
        r.render(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    r.close()


def test_similarity_align_and_grid():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(50, 3))
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    Q = 1.7 * P @ R.T + [0.3, -2.0, 1.0]
    assert np.allclose(similarity_align(P, Q), Q, atol=1e-9)
    m = np.ones(50, bool)
    m[:10] = False
    Pn = P.copy()
    Pn[:10] += 5.0  # outliers outside the mask do not move the fit
    assert np.allclose(similarity_align(Pn, Q, m)[10:], Q[10:], atol=1e-9)
    g = grid_image(np.ones((2, 3, 4, 5)) * 0.5, gap=1)
    assert g.shape == (2 * 5 + 1, 3 * 6 + 1) and g.dtype == np.uint8 and g[1, 1] == 128 and g[0, 0] == 255


def test_grid_labels_take_a_band_and_must_match():
    t = np.full((2, 3, 32, 32), 0.5)
    plain = grid_image(t)
    lab = grid_image(t, row_labels=["smiling", "pouting"], col_labels=["samples", "", "real"])
    assert lab.shape[0] > plain.shape[0] and lab.shape[1] > plain.shape[1]
    band = lab[:, : lab.shape[1] - plain.shape[1]]
    assert band.min() < 128  # text was written in the left band
    assert np.all(lab[-plain.shape[0] + 2:, -plain.shape[1] + 2:][:32, :32] == 128)  # the first tile itself is intact
    with pytest.raises(ValueError, match="row_labels"):
        grid_image(t, row_labels=["one"])
