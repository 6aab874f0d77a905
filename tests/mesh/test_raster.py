"""The z-buffer (:func:`geoface.mesh.raster.rasterize_mesh`): its compiled loop writes what the
NumPy loop writes, to the last bit, and both see what a pinhole camera sees."""
from __future__ import annotations

import numpy as np
import pytest

from geoface.camera import look_at
from geoface.mesh.raster import _native_zbuffer, rasterize_mesh


def _same(a, b):
    for u, v in zip(a, b):
        assert u.dtype == v.dtype and np.array_equal(u, v)


@pytest.mark.skipif(_native_zbuffer() is None, reason="the compiled z-buffer is not built (setup.py builds it)")
def test_the_compiled_loop_writes_what_the_numpy_loop_writes():
    from geoface.synth.ict import ict_head, load_ict_model
    from geoface.track.look import any_up, camera_at, principal_frame, search_views

    head = ict_head(load_ict_model(), seed=1)
    V, F = head.V.astype(np.float64), head.F.astype(np.int64)
    c, r, E = principal_frame(V, F)
    for res, g in [(64, g) for g in search_views()[::5]] + [(256, search_views()[4]), (333, search_views()[13])]:
        cam = camera_at(c, E @ g, E @ any_up(g), r, res)
        _same(rasterize_mesh(V, F, cam, native=False), rasterize_mesh(V, F, cam))
    # a soup of crossing triangles, some drawn twice (equally near: the first is kept)
    rng = np.random.default_rng(0)
    Vr = rng.normal(size=(300, 3))
    Fr = rng.integers(0, 300, (400, 3))
    Fr = Fr[(Fr[:, 0] != Fr[:, 1]) & (Fr[:, 1] != Fr[:, 2]) & (Fr[:, 0] != Fr[:, 2])]
    n0 = len(Fr)
    Fr = np.vstack([Fr, Fr[:60]])
    cam = look_at(np.array([0.0, 0.0, 6.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]), width=97, height=61, fov_y_deg=40)
    a, b = rasterize_mesh(Vr, Fr, cam, native=False), rasterize_mesh(Vr, Fr, cam)
    _same(a, b)
    assert (a[0] >= 0).mean() > 0.3 and np.isin(np.arange(60), a[0]).any() and not (a[0] >= n0).any()


@pytest.mark.parametrize("native", [False, True])
def test_a_square_in_front_of_another_hides_it_and_depth_is_exact(native):
    """Two squares facing the camera at depths 2 and 3: the nearer one is seen where they overlap,
    the depth of every pixel is its square's, and the barycentric weights rebuild the pixel's ray."""
    sq = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    V = np.vstack([sq + [0.5, 0, -3], sq * 0.5 + [0, 0, -2]])
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    cam = look_at(np.zeros(3), np.array([0.0, 0, -1]), np.array([0.0, 1, 0]), width=64, height=64, fov_y_deg=60)
    face, bary, depth = rasterize_mesh(V, F, cam, native=native)
    near, far = np.isin(face, [2, 3]), np.isin(face, [0, 1])
    assert near.sum() > 100 and far.sum() > 100
    assert np.allclose(depth[near], 2.0) and np.allclose(depth[far], 3.0) and np.isinf(depth[face < 0]).all()
    P = np.einsum("hwk,hwkd->hwd", bary, V[F[np.maximum(face, 0)]])[face >= 0]
    uv, z = cam.project(P)
    j, i = np.nonzero(face >= 0)[1], np.nonzero(face >= 0)[0]
    assert np.allclose(uv, np.c_[j + 0.5, i + 0.5], atol=1e-6)
