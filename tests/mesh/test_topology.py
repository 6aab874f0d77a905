import numpy as np
import pytest

from geoface.mesh import topology_report
from geoface.synth import cylinder, disk_grid, genus2, hemisphere, irregular_flat_patch, mobius_strip, sphere, square_grid, torus

from tests.helpers import angle_defects


@pytest.mark.parametrize(
    "make, chi, genus, loops",
    [
        (lambda: square_grid(7), 1, 0, 1),
        (lambda: disk_grid(5), 1, 0, 1),
        (lambda: irregular_flat_patch(300, seed=3), 1, 0, 1),
        (lambda: hemisphere(1.0, 8), 1, 0, 1),
        (lambda: sphere(1.0, 3), 2, 0, 0),
        (lambda: cylinder(), 0, 0, 2),
        (lambda: torus(), 0, 1, 0),
        (lambda: genus2(40), -2, 2, 0),
    ],
)
def test_euler_genus_boundaries(make, chi, genus, loops):
    V, F = make()
    r = topology_report(V, F)
    assert r.euler_characteristic == chi
    assert r.genus == genus
    assert r.boundary_loops == loops
    assert r.manifold and r.consistently_oriented and r.orientable
    assert r.components == 1
    assert r.is_disk == (chi == 1 and loops == 1)
    assert r.closed == (loops == 0)


@pytest.mark.parametrize("make", [lambda: sphere(1.0, 3), lambda: torus(1.0, 0.3, 40, 20), lambda: genus2(40)])
def test_gauss_bonnet_on_closed_surfaces(make):
    # total angle defect of a closed polyhedral surface is exactly 2*pi*chi
    V, F = make()
    r = topology_report(V, F)
    assert angle_defects(V, F).sum() == pytest.approx(2 * np.pi * r.euler_characteristic, abs=1e-8)


def test_detects_nonmanifold_edge_and_vertex(fin, bowtie):
    r = topology_report(*fin)
    assert r.nonmanifold_edges == 1 and not r.manifold and r.genus is None and not r.is_disk
    r = topology_report(*bowtie)
    assert r.nonmanifold_vertices == 1 and r.nonmanifold_edges == 0 and not r.manifold


def test_detects_inconsistent_orientation_but_orientable():
    V, F = square_grid(5)
    F = F.copy()
    f = int(np.flatnonzero((F == 12).any(1))[0])  # a face around the centre vertex: all edges interior
    F[f] = F[f, ::-1]
    r = topology_report(V, F)
    assert not r.consistently_oriented and r.orientable
    assert r.inconsistent_edges == 3
    assert not r.is_disk


def test_moebius_strip_is_nonorientable():
    r = topology_report(*mobius_strip())
    assert not r.orientable and r.genus is None and r.boundary_loops == 1


def test_counts_defects():
    V, F = square_grid(4)
    # vertex 16 duplicates vertex 0 and is used by a face; vertex 17 is unreferenced
    V2 = np.vstack([V, V[:1] + 1e-12, [[5, 5, 5]]])
    F2 = np.vstack([F, F[:1], [[0, 1, 1]], [[16, 1, 5]]])
    r = topology_report(V2, F2)
    assert r.duplicate_faces == 1
    assert r.degenerate_faces == 1
    assert r.unreferenced_vertices == 1
    assert r.duplicate_vertices == 1
    assert np.allclose(r.bbox_min, 0) and np.allclose(r.bbox_max, [1, 1, 0])  # referenced vertices only
    assert r.bbox_diagonal == pytest.approx(np.sqrt(2))


def test_report_serialises():
    import json

    r = topology_report(*torus())
    d = json.loads(r.to_json())
    assert d["genus"] == 1 and d["boundary_loops"] == 0
    assert "genus" in r.format()
