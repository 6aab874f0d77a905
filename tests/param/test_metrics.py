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
