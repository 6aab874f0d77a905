import numpy as np
import pytest

from geoface.param.intrinsic import (
    angle_sums,
    boundary_mask,
    clausen2,
    corner_angles,
    cotan_laplacian,
    cotan_weights,
    curvature,
    edge_lengths,
    face_area,
    lobachevsky,
)
from geoface.synth import genus2, irregular_flat_patch, spherical_cap, sphere, square_grid, torus


def test_angles_of_known_triangles():
    l = np.array([[1.0, 1.0, 1.0], [3.0, 4.0, 5.0], [1.0, 1.0, np.sqrt(2.0)]])
    a = corner_angles(l)
    assert np.allclose(a[0], np.pi / 3, atol=1e-15)
    assert a[1, 2] == pytest.approx(np.pi / 2, abs=1e-15)  # opposite the 5
    assert a[2, 2] == pytest.approx(np.pi / 2, abs=1e-15)
    assert np.allclose(a.sum(1), np.pi, atol=1e-14)
    assert face_area(l[1:2])[0] == pytest.approx(6.0, rel=1e-15)


def test_degenerate_triangles_extend_continuously():
    l = np.array([[3.0, 1.0, 1.0], [2.0, 1.0, 1.0], [1.0, 1e-9, 1.0]])  # violated, flat, needle
    a = corner_angles(l)
    assert np.isfinite(a).all()
    assert a[0].tolist() == [np.pi, 0.0, 0.0]
    assert a[1, 0] == pytest.approx(np.pi) and np.allclose(a.sum(1), np.pi)
    assert cotan_weights(l[:1]).tolist() == [[0.0, 0.0, 0.0]]


@pytest.mark.parametrize("make", [lambda: sphere(1.0, 3), lambda: torus(), lambda: genus2(40), lambda: square_grid(7), lambda: spherical_cap(1, 1, 8)])
def test_gauss_bonnet_for_any_lengths(make):
    V, F = make()
    from geoface.mesh import topology_report

    chi = topology_report(V, F).euler_characteristic
    l = edge_lengths(V, F)
    assert curvature(l, F, len(V)).sum() == pytest.approx(2 * np.pi * chi, abs=1e-9)
    # ... and for arbitrary conformally scaled lengths (intrinsic, not positions)
    u = np.random.default_rng(0).normal(size=len(V)) * 0.05
    l2 = l * np.exp(0.5 * (u[F[:, [1, 2, 0]]] + u[F[:, [2, 0, 1]]]))
    assert curvature(l2, F, len(V)).sum() == pytest.approx(2 * np.pi * chi, abs=1e-9)


def test_flat_patch_has_zero_interior_curvature():
    V, F = irregular_flat_patch(300, seed=2)
    k = curvature(edge_lengths(V, F), F, len(V))
    inner = ~boundary_mask(F, len(V))
    assert np.abs(k[inner]).max() < 1e-12
    assert angle_sums(edge_lengths(V, F), F, len(V))[inner] == pytest.approx(2 * np.pi)


def test_cotan_laplacian_properties():
    V, F = irregular_flat_patch(400, seed=0)
    L = cotan_laplacian(edge_lengths(V, F), F, len(V))
    assert abs(L - L.T).max() < 1e-14
    assert np.abs(L @ np.ones(len(V))).max() < 1e-12  # constants in the kernel
    # linear functions are harmonic inside a flat patch
    inner = ~boundary_mask(F, len(V))
    assert np.abs((L @ V[:, 0])[inner]).max() < 1e-12
    # x^T L x = Dirichlet energy = area * |grad x|^2 = 1 for x on the unit square
    assert V[:, 0] @ (L @ V[:, 0]) == pytest.approx(1.0, rel=1e-12)
    assert np.linalg.eigvalsh(L.toarray()).min() > -1e-10  # positive semi-definite


def test_clausen_and_lobachevsky():
    from scipy.integrate import quad

    for x in [0.3, 1.0, np.pi / 2, 2.5, np.pi, 5.0, -2.0]:
        ref = -quad(lambda t: np.log(abs(2 * np.sin(t / 2))), 0, x, limit=200)[0]
        assert clausen2(np.array([x]))[0] == pytest.approx(ref, abs=1e-13)
    x = 1e-8  # small x: Cl2(x) = x - x log x + x^3 / 72 + ...
    assert clausen2(np.array([x]))[0] == pytest.approx(x - x * np.log(x), rel=1e-15)
    # Л(pi/6) = (3/2) Л(pi/3)... and Л is pi-periodic and odd
    x = np.linspace(-3, 3, 13)
    assert np.allclose(lobachevsky(x + np.pi), lobachevsky(x), atol=1e-14)
    assert np.allclose(lobachevsky(-x), -lobachevsky(x), atol=1e-15)
    assert lobachevsky(np.array([np.pi / 6]))[0] == pytest.approx(1.5 * lobachevsky(np.array([np.pi / 3]))[0], rel=1e-13)
