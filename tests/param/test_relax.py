"""Relaxing a fold-free map towards the measure-preserving one (geoface.param.relax): the
barrier never lets a triangle fold, a consistent target is reached, a folded target is
approached as far as the barrier allows, and an untangled male02-like squeeze is undone."""
from __future__ import annotations

import numpy as np

from geoface.mesh.core import signed_uv_areas, vertex_areas
from geoface.param.relax import _max_step, relax_map, triangle_targets
from tests.helpers import planar_grid


def _log_area_error(F, x, T):
    A = signed_uv_areas(F, x)
    return float(np.mean(np.abs(np.log(np.abs(A) / A.sum() / (T / T.sum())))))


def test_the_step_limit_is_where_a_triangle_first_reaches_zero_area():
    F = np.array([[0, 1, 2]])
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    d = np.zeros_like(x)
    d[2] = [0.0, -1.0]  # apex moves straight down: area 1/2 (1 - α), zero at α = 1
    assert abs(_max_step(F, x, d, signed_uv_areas(F, x)) - 1.0) < 1e-12
    d[2] = [3.0, -0.5]  # sliding sideways keeps the height until α = 2
    assert abs(_max_step(F, x, d, signed_uv_areas(F, x)) - 2.0) < 1e-12
    d[:] = 0.0
    d[1] = [-1.0, 1.0]  # quadratic case: base vertex moves towards the apex: zero at α = 1/2
    d[2] = [1.0, -1.0]
    a = _max_step(F, x, d, signed_uv_areas(F, x))
    y = x + a * d
    assert abs(signed_uv_areas(F, y)[0]) < 1e-12 and a > 0


def test_a_squeezed_column_relaxes_back_to_theplanar_grid():
    """The target is the uniform grid; the start pulls the middle of the square together (along
    rays from the centre, r -> 0.45 (r / 0.45)^1.6: fold-free, the centre's triangles a tenth
    of their area). The relaxed map is back on the grid."""
    F, uv, inner = planar_grid()
    V3 = np.column_stack([uv, np.zeros(len(uv))])
    T = triangle_targets(V3, F, vertex_areas(V3, F))
    d = uv - 0.5
    r = np.abs(d).max(1)
    scale = np.where(r < 0.45, (np.maximum(r, 1e-12) / 0.45) ** 0.6, 1.0)
    x0 = 0.5 + d * scale[:, None]
    assert (signed_uv_areas(F, x0) > 0).all() and _log_area_error(F, x0, T) > 0.3
    x, info = relax_map(F, x0, uv, T, movable=inner)
    assert info["kept"] and (signed_uv_areas(F, x) > 0).all()
    assert info["energy_after"] < 1e-3 * info["energy_before"]
    assert np.abs(x - uv).max() < 1e-3 and _log_area_error(F, x, T) < 0.01
    assert np.array_equal(x[~inner], x0[~inner])  # the boundary stays


def test_a_folded_target_is_approached_without_a_fold():
    """The target mirrors a patch (60+ triangles folded). From a fold-free start the relaxed map
    never folds, keeps every triangle open, and gets far closer to the target areas than the start."""
    F, uv, inner = planar_grid()
    V3 = np.column_stack([uv, np.zeros(len(uv))])
    T = triangle_targets(V3, F, vertex_areas(V3, F))
    h = 1.0 / 20
    patch = (np.abs(uv[:, 0] - 0.5) < 3.5 * h) & (np.abs(uv[:, 1] - 0.5) < 3.5 * h)
    target = uv.copy()
    target[patch, 0] = 1.0 - target[patch, 0]
    assert (signed_uv_areas(F, target) <= 0).sum() > 50
    x0 = uv + 0.3 * (uv - 0.5) * (uv - 0.5).prod(1, keepdims=True)  # a smooth fold-free distortion
    x0[~inner] = uv[~inner]
    assert (signed_uv_areas(F, x0) > 0).all()
    x, info = relax_map(F, x0, target, T, movable=inner)
    A = signed_uv_areas(F, x)
    assert info["kept"] and (A > 0).all() and A.min() > 0.05 * T.min()
    assert info["energy_after"] < info["energy_before"]
    far = (np.abs(uv[:, 0] - 0.5) > 9.5 * h) | (np.abs(uv[:, 1] - 0.5) > 9.5 * h)
    assert np.abs(x[far] - target[far]).max() < 0.02


def test_a_folded_start_is_returned_unchanged():
    F, uv, inner = planar_grid(6)
    V3 = np.column_stack([uv, np.zeros(len(uv))])
    x0 = uv.copy()
    x0[inner.nonzero()[0][0]] += [0.6, 0.6]  # folds its triangles
    assert (signed_uv_areas(F, x0) <= 0).any()
    x, info = relax_map(F, x0, uv, triangle_targets(V3, F, vertex_areas(V3, F)), movable=inner)
    assert not info["kept"] and np.array_equal(x, x0)
