import numpy as np
import pytest

from geoface.errors import InvalidMeshError
from geoface.param.metrics import distortion
from geoface.synth import irregular_flat_patch, square_grid


def test_similarity_maps_are_conformal_and_area_preserving():
    V, F = irregular_flat_patch(300, seed=1)
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    uv = 3.0 * V[:, :2] @ R.T + [5, -2]
    s = distortion(V, F, uv).summary()
    assert s["qc_max"] == pytest.approx(1.0, abs=1e-9)
    assert s["log_area_abs_p95"] < 1e-9 and s["flipped"] == 0


def test_known_stretch_and_area_ratio():
    V, F = square_grid(6)
    uv = V[:, :2] * [2.0, 1.0]  # stretch x by 2: qc 2 everywhere, uniform area ratio
    d = distortion(V, F, uv)
    assert np.allclose(d.qc, 2.0)
    assert np.allclose(d.log_area, 0.0, atol=1e-12)  # totals are normalised
    uv2 = V[:, :2].copy()
    uv2[:, 0] = uv2[:, 0] ** 2  # compresses near x = 0: area ratio varies
    assert np.abs(distortion(V, F, uv2).log_area).max() > 0.5


def test_flips_detected():
    V, F = square_grid(5)
    uv = V[:, :2].copy()
    uv[12] = [0.9, 0.9]  # drag the centre vertex across its neighbours
    s = distortion(V, F, uv).summary()
    assert s["flipped"] > 0
    mirrored = distortion(V, F, V[:, :2] * [-1, 1]).summary()
    assert mirrored["flipped"] == len(F)


def test_bad_uv_shape():
    V, F = square_grid(3)
    with pytest.raises(InvalidMeshError, match="UV"):
        distortion(V, F, np.zeros((3, 2)))


def test_map_distortion_equals_per_triangle_distortion_for_linear_maps():
    from geoface.param.metrics import linear_map, map_distortion

    V, F = irregular_flat_patch(200, seed=3)
    rng = np.random.default_rng(0)
    uv = V[:, :2] @ np.array([[1.3, 0.2], [-0.1, 0.8]]) + 0.02 * rng.standard_normal((len(V), 2))
    d = distortion(V, F, uv)
    md = map_distortion(V, F, linear_map(F, uv), level=3)
    ok = ~d.flipped
    assert np.allclose(md.qc[ok], d.qc[ok], rtol=1e-6)
    assert np.allclose(md.log_area[ok], d.log_area[ok], atol=1e-6)
    assert np.array_equal(md.flipped > 0, d.flipped)


def test_map_distortion_sees_non_linear_maps():
    from geoface.param.metrics import map_distortion

    V, F = square_grid(2)  # two triangles: a linear sampling of z -> z^2 would hide its distortion

    def square(face, bary):
        p = np.einsum("ki,kij->kj", bary, V[F[face], :2]) + [1.0, 0.5]
        z = (p[:, 0] + 1j * p[:, 1]) ** 2
        return np.stack([z.real, z.imag], 1)

    def shear(face, bary):  # (x, y) -> (x + y^2, y): qc grows with y
        p = np.einsum("ki,kij->kj", bary, V[F[face], :2])
        return np.stack([p[:, 0] + p[:, 1] ** 2, p[:, 1]], 1)

    assert map_distortion(V, F, square, level=6).summary()["qc_max"] < 1 + 1e-4  # holomorphic: conformal
    s = map_distortion(V, F, shear, level=6).summary()
    assert s["qc_max"] > 1.5 and s["flipped"] == 0
    mirror = lambda f, b: square(f, b) * [1, -1]  # noqa: E731
    assert map_distortion(V, F, mirror, level=2).summary()["flipped"] == len(F)
