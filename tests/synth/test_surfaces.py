"""Analytic surfaces: exact or convergent areas and curvature, stated topology."""

import numpy as np
import pytest

from geoface.errors import InvalidMeshError
from geoface.mesh import topology_report
from geoface.mesh.core import boundary_loops, face_areas, face_normals
from geoface.synth import cylinder, disk_grid, genus2, hemisphere, irregular_flat_patch, punch_holes, sphere, spherical_cap, square_grid, torus
from tests.helpers import angle_defects


def interior(F, n):
    b = np.zeros(n, bool)
    for lp in boundary_loops(F):
        b[lp] = True
    return ~b


def test_flat_patches_are_flat_with_exact_area():
    for V, F, area in [(*square_grid(9, 2.0), 4.0), (*irregular_flat_patch(400, seed=1), 1.0)]:
        assert face_areas(V, F).sum() == pytest.approx(area, rel=1e-12)
        assert np.allclose(face_normals(V, F), [0, 0, 1])  # counter-clockwise seen from +z
        assert np.abs(angle_defects(V, F)[interior(F, len(V))]).max() < 1e-12  # zero curvature
    V, F = disk_grid(10, radius=1.0)
    assert face_areas(V, F).sum() == pytest.approx(np.pi, rel=0.02)  # inscribed polygons


@pytest.mark.parametrize("angle", [0.5, 1.0, np.pi / 2, 2.0])
def test_spherical_cap_area_and_total_curvature(angle):
    R = 2.0
    V, F = spherical_cap(R, angle, 24)
    assert np.allclose(np.linalg.norm(V, axis=1), R)
    assert face_areas(V, F).sum() == pytest.approx(2 * np.pi * R * R * (1 - np.cos(angle)), rel=0.01)
    # Gauss-Bonnet for a disk: interior defects + boundary turning = 2*pi; the interior
    # part converges to the cap's integrated curvature 2*pi*(1 - cos(angle))
    K = angle_defects(V, F)[interior(F, len(V))].sum()
    assert K == pytest.approx(2 * np.pi * (1 - np.cos(angle)), rel=0.06)
    r = topology_report(V, F)
    assert r.is_disk


def test_closed_surfaces():
    V, F = sphere(1.0, 4)
    assert face_areas(V, F).sum() == pytest.approx(4 * np.pi, rel=0.01)
    V, F = torus(1.0, 0.25, 96, 48)
    assert face_areas(V, F).sum() == pytest.approx(4 * np.pi**2 * 0.25, rel=0.01)
    assert topology_report(V, F).genus == 1
    V, F = genus2(64)
    r = topology_report(V, F)
    assert r.genus == 2 and r.closed and r.components == 1
    assert r.degenerate_faces == 0


def test_tube_and_hemisphere():
    V, F = cylinder(0.5, 2.0, 96, 8)
    assert face_areas(V, F).sum() == pytest.approx(2 * np.pi * 0.5 * 2.0, rel=0.01)
    C = V[F].mean(1)
    radial = C * [1, 1, 0]
    assert (np.einsum("ij,ij->i", face_normals(V, F), radial) > 0).all()  # outward
    V, F = hemisphere(1.0, 20)
    assert face_areas(V, F).sum() == pytest.approx(2 * np.pi, rel=0.01)


def test_punch_holes_is_deterministic_and_avoids_the_rim():
    V, F = square_grid(31)
    a = punch_holes(V, F, n_holes=3, radius=0.05, seed=7)[1]
    b = punch_holes(V, F, n_holes=3, radius=0.05, seed=7)[1]
    assert np.array_equal(a, b) and len(a) < len(F)
    assert len(boundary_loops(F)[0]) == max(len(lp) for lp in boundary_loops(a))  # rim intact


def test_bad_arguments():
    with pytest.raises(InvalidMeshError):
        square_grid(1)
    with pytest.raises(InvalidMeshError):
        torus(1.0, 2.0)
    with pytest.raises(InvalidMeshError):
        spherical_cap(1.0, 4.0)
