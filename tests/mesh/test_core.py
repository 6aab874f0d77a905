import numpy as np
import pytest

from geoface.errors import InvalidMeshError
from geoface.mesh import core
from geoface.synth import cylinder, disk_grid, sphere, square_grid, torus


def test_check_mesh_converts_and_validates(tri):
    V, F = core.check_mesh(*tri)
    assert V.dtype == np.float64 and F.dtype == np.int64
    with pytest.raises(InvalidMeshError, match=r"F must have shape \(m, 3\); got \(1, 4\)"):
        core.check_mesh(tri[0], [[0, 1, 2, 0]])
    with pytest.raises(InvalidMeshError, match="NaN"):
        core.check_mesh([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(InvalidMeshError, match="indexes vertices"):
        core.check_mesh(tri[0], [[0, 1, 3]])
    with pytest.raises(InvalidMeshError, match="indexes vertices"):
        core.check_mesh(tri[0], [[0, -1, 2]])
    with pytest.raises(InvalidMeshError, match="empty"):
        core.check_mesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(InvalidMeshError, match="integer"):
        core.check_mesh(tri[0], [[0, 1, 1.5]])


def test_areas_exact_on_flat_grid():
    V, F = square_grid(9, size=2.0)
    assert core.face_areas(V, F).sum() == pytest.approx(4.0, rel=1e-12)
    va = core.vertex_areas(V, F)
    assert va.sum() == pytest.approx(4.0, rel=1e-12)
    # an interior vertex where 8 triangles (h^2/2 each) meet carries a third of them
    h = 2.0 / 8
    assert va.max() == pytest.approx(8 * h * h / 6, rel=1e-12)


def test_normals_point_out_of_sphere():
    V, F = sphere(1.0, 4)
    N = core.vertex_normals(V, F)
    assert np.allclose(np.linalg.norm(N, axis=1), 1)
    assert (np.einsum("ij,ij->i", N, V) > 0.98).all()
    assert core.signed_volume(V, F) == pytest.approx(4 / 3 * np.pi, rel=0.01)


def test_edge_topology_counts():
    V, F = torus(1.0, 0.3, 16, 8)
    et = core.edge_topology(F)
    assert len(et.E) == 3 * len(F) // 2  # closed manifold: every edge has two faces
    assert (et.edge_faces == 2).all()
    pairs = core.manifold_halfedge_pairs(et)
    assert len(pairs) == len(et.E)
    assert (et.he_edge[pairs[:, 0]] == et.he_edge[pairs[:, 1]]).all()


def test_boundary_loops_of_a_tube():
    V, F = cylinder(radius=0.5, height=1.0, n_around=40, n_high=5)
    loops = core.boundary_loops(F)
    assert sorted(len(lp) for lp in loops) == [40, 40]
    for lp in loops:
        # inscribed 40-gon perimeter
        assert core.loop_length(V, lp) == pytest.approx(40 * 2 * 0.5 * np.sin(np.pi / 40), rel=1e-12)
        # loop direction follows the faces' half-edges
        src, dst = F.ravel(), F[:, [1, 2, 0]].ravel()
        have = set(zip(src.tolist(), dst.tolist()))
        assert all((int(a), int(b)) in have for a, b in zip(lp, np.roll(lp, -1)))


def test_disk_loop_and_components():
    V, F = disk_grid(6)
    assert len(core.boundary_loops(F)) == 1
    n, lab = core.face_components(np.vstack([F, F + len(V)]), 2 * len(V))
    assert n == 2 and np.bincount(lab).tolist() == [len(F), len(F)]


def test_vertex_fans_detect_bowtie(bowtie):
    V, F = bowtie
    assert core.nonmanifold_vertices(F, len(V)).tolist() == [0]
    V2, F2 = square_grid(4)
    assert len(core.nonmanifold_vertices(F2, len(V2))) == 0


def test_remove_unreferenced():
    V, F = square_grid(3)
    V2 = np.vstack([V, [[9, 9, 9]]])
    V3, F3, kept = core.remove_unreferenced(V2, F)
    assert len(V3) == len(V) and np.array_equal(kept, np.arange(len(V)))
    assert np.array_equal(V3[F3], V[F])


def test_degenerate_and_duplicate_faces():
    V, F = square_grid(3)
    F2 = np.vstack([F, F[:2], [[0, 0, 1]]])
    assert core.duplicate_faces(F2).sum() == 2
    assert core.degenerate_faces(V, F2)[-1]
    assert core.degenerate_faces(V, F2).sum() == 1


def test_triple_keys_stay_exact_above_two_million_vertices():
    """(a n + b) n + c wraps around int64 above 2^21 vertices: these two faces of a 3M-vertex
    mesh share that key modulo 2^64 (the repair steps matched faces by it unguarded)."""
    from geoface.mesh.core import TRIPLE_KEY_LIMIT, duplicate_faces, triple_keys

    n = 3_000_000
    r1, r2 = (2088113, 2109853, 2981209), (38475, 1418617, 1429593)
    assert ((r1[0] * n + r1[1]) * n + r1[2]) % 2**64 == (r2[0] * n + r2[1]) * n + r2[2]  # the collision
    assert n > TRIPLE_KEY_LIMIT
    F = np.array([r1, r2, r1[::-1]])
    assert duplicate_faces(F).tolist() == [False, False, True]
    ka, kb = triple_keys(np.array([r1, r2]), np.array([r2]), n=n)
    assert ka[0] != ka[1] and kb[0] == ka[1]
    small = triple_keys(np.array([[1, 2, 3], [3, 2, 1], [1, 2, 3]]), n=10)[0]
    assert small[0] == small[2] != small[1]
