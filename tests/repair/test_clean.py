import numpy as np
import pytest

from geoface.mesh import topology_report
from geoface.mesh.core import face_areas
from geoface.repair import clean, make_manifold, merge_vertices, remove_degenerate_faces
from geoface.synth import mobius_strip, square_grid, torus


def soup(V, F, jitter=0.0, seed=0):
    """Every face gets its own three vertices (optionally jittered): a triangle soup."""
    rng = np.random.default_rng(seed)
    V2 = V[F.ravel()] + jitter * rng.standard_normal((3 * len(F), 3))
    return V2, np.arange(3 * len(F)).reshape(-1, 3)


def test_merge_rebuilds_connectivity_from_a_soup():
    V, F = torus(1.0, 0.3, 24, 12)
    Vs, Fs = soup(V, F, jitter=1e-9)
    assert topology_report(Vs, Fs).components == len(F)
    res = merge_vertices(Vs, Fs)
    r = topology_report(res.V, res.F)
    assert len(res.V) == len(V) and r.genus == 1 and r.closed
    assert res.changes[0]["merged"] == 3 * len(F) - len(V)
    # representatives are original soup vertices, so positions are exact copies
    assert np.array_equal(res.V, Vs[res.vertex_map])


def test_merge_respects_tolerance():
    V, F = square_grid(4)
    Vs, Fs = soup(V, F, jitter=1e-3)  # far above the default tolerance
    assert len(merge_vertices(Vs, Fs).V) == len(Vs)
    assert len(merge_vertices(Vs, Fs, tolerance=0.05).V) == len(V)


def test_cap_triangles_are_flipped_not_deleted():
    # a flat grid where a vertex sits exactly on the edge of a neighbouring triangle:
    # triangles (0,1,2) with 2 on segment 0-1 are caps; the surface must stay whole
    V = np.array([[0.0, 0, 0], [2, 0, 0], [1, 0, 0], [1, 1, 0], [1, -1, 0]])
    F = np.array([[0, 2, 3], [2, 1, 3], [0, 1, 2], [1, 0, 4]])  # (0,1,2) is a zero-area cap
    res = remove_degenerate_faces(V, F)
    r = topology_report(res.V, res.F)
    assert r.degenerate_faces == 0 and r.manifold
    assert face_areas(res.V, res.F).sum() == pytest.approx(2.0, abs=1e-12)  # nothing lost
    assert r.boundary_loops == 1 and r.components == 1


def test_repeated_and_duplicate_faces_removed():
    V, F = square_grid(4)
    F2 = np.vstack([F, F[:3], [[0, 0, 5]], F[4:5, ::-1]])
    res = remove_degenerate_faces(V, F2)
    assert len(res.F) == len(F)
    assert {c["step"] for c in res.changes} >= {"remove_degenerate_faces", "remove_duplicate_faces"}


def test_bowtie_vertex_split(bowtie):
    res = make_manifold(*bowtie)
    r = topology_report(res.V, res.F)
    assert r.manifold and len(res.V) == 6 and r.components == 2
    assert sorted(res.vertex_map.tolist()) == [0, 0, 1, 2, 3, 4]
    # copies are separated slightly (so cleaning again changes nothing)
    assert 0 < np.linalg.norm(res.V[0] - res.V[5]) < 0.05


def test_fin_edge_split(fin):
    V, F = fin
    res = make_manifold(V, F)
    r = topology_report(res.V, res.F)
    assert r.manifold and r.nonmanifold_edges == 0
    assert len(res.F) == len(F)  # split, not deleted


def test_orientation_fixed_majority_kept():
    V, F = torus(1.0, 0.3, 20, 10)
    rng = np.random.default_rng(1)
    flip = rng.random(len(F)) < 0.3
    Fb = np.where(flip[:, None], F[:, ::-1], F)
    res = make_manifold(V, Fb)
    assert topology_report(res.V, res.F).consistently_oriented
    assert np.array_equal(res.F, F)  # outward, the majority orientation, is restored exactly


def test_moebius_cut_to_a_disk():
    res = clean(*mobius_strip())
    r = topology_report(res.V, res.F)
    assert r.is_disk
    assert any(c["step"] == "cut_nonorientable" for c in res.changes)


def test_clean_is_idempotent_and_a_noop_on_clean_input(fin):
    V, F = square_grid(6)
    res = clean(V, F)
    assert res.changes == [] and np.array_equal(res.F, F) and np.array_equal(res.V, V)
    once = clean(*fin)
    twice = clean(once.V, once.F)
    assert twice.changes == []


def test_fins_are_removed_but_a_double_sided_export_is_kept():
    V, F = square_grid(4)
    apex = len(V)
    V2 = np.vstack([V, [[0.5, 0.5, 0.3]]])
    a, b = int(F[5, 0]), int(F[5, 1])
    F2 = np.vstack([F, [[a, b, apex], [b, a, apex]]])  # a sheet hanging off edge (a, b), both sides
    res = remove_degenerate_faces(V2, F2)
    assert len(res.F) == len(F) and apex not in res.F
    assert any(c["step"] == "remove_fins" and c["removed"] == 2 for c in res.changes)
    both = np.vstack([F, F[:, ::-1]])  # every face also reversed: a double-sided export, not fins
    res = remove_degenerate_faces(V, both)
    assert len(res.F) == len(F) and not any(c["step"] == "remove_fins" for c in res.changes)
