import numpy as np
import pytest

from geoface.mesh import topology_report
from geoface.mesh.core import boundary_loops, face_areas
from geoface.repair import clean, fill_holes
from geoface.repair.holes import minimal_area_triangulation, triangulate_loop
from geoface.synth import punch_holes, sphere, square_grid


def test_minimal_area_triangulation_of_planar_polygons():
    # any triangulation of a convex planar polygon has the polygon's area;
    # for a non-convex one the minimum (no overlaps) is also the polygon's area
    t = np.linspace(0, 2 * np.pi, 9)[:-1]
    P = np.stack([np.cos(t), np.sin(t), np.zeros(8)], 1)
    T = minimal_area_triangulation(P)
    assert T.shape == (6, 3)
    A = 0.5 * np.linalg.norm(np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]), axis=1).sum()
    assert A == pytest.approx(8 * 0.5 * np.sin(2 * np.pi / 8), rel=1e-12)
    star = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [1, 0.5, 0], [0, 2, 0]], float)  # non-convex
    T = minimal_area_triangulation(star)
    A = 0.5 * np.linalg.norm(np.cross(star[T[:, 1]] - star[T[:, 0]], star[T[:, 2]] - star[T[:, 0]]), axis=1).sum()
    assert A == pytest.approx(4 - 1.5, rel=1e-12)


def test_existing_edges_are_never_duplicated():
    # loop 0-1-2-3 where chord 0-2 already exists elsewhere in the mesh
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    from geoface.mesh.core import edge_keys

    keys = edge_keys(np.array([[0, 2, 1]]))
    tris, pts = triangulate_loop(V, np.array([0, 1, 2, 3]), keys)
    used = {tuple(sorted(e)) for t in tris for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    assert (0, 2) not in used


def test_flat_hole_filled_flat_with_exact_area():
    V, F = square_grid(21)
    Vh, Fh = punch_holes(V, F, n_holes=2, radius=0.08, seed=2)
    c = clean(Vh, Fh)
    assert topology_report(c.V, c.F).boundary_loops == 3
    res = fill_holes(c.V, c.F)  # keeps the longest loop: the square's rim
    r = topology_report(res.V, res.F)
    assert r.is_disk and r.degenerate_faces == 0
    assert np.abs(res.V[:, 2]).max() < 1e-12  # a flat hole is filled flat (fairing keeps the plane)
    assert face_areas(res.V, res.F).sum() == pytest.approx(1.0, abs=1e-12)
    assert sum(ch["area_added"] for ch in res.changes) == pytest.approx(1.0 - face_areas(c.V, c.F).sum(), abs=1e-12)


def test_sphere_holes_filled_smoothly():
    V, F = sphere(1.0, 4)
    Vh, Fh = punch_holes(V, F, n_holes=4, radius=0.08, seed=1)
    c = clean(Vh, Fh)
    res = fill_holes(c.V, c.F, keep="none")
    r = topology_report(res.V, res.F)
    assert r.closed and r.genus == 0 and r.degenerate_faces == 0 and r.consistently_oriented
    # the faired patches stay close to the missing sphere (bi-Laplacian ~ smooth continuation)
    assert np.abs(np.linalg.norm(res.V, axis=1) - 1).max() < 0.02
    assert r.surface_area == pytest.approx(face_areas(V, F).sum(), rel=0.01)
    # refinement: patch edges are about as long as the surrounding ones
    new = res.face_map < 0
    P = res.V[res.F[new]]
    e = np.linalg.norm(P[:, [1, 2, 0]] - P, axis=2)
    P0 = V[F]
    e0 = np.linalg.norm(P0[:, [1, 2, 0]] - P0, axis=2).mean()
    assert 0.6 * e0 < e.mean() < 1.4 * e0


def test_keep_options():
    V, F = square_grid(11)
    Vh, Fh = punch_holes(V, F, n_holes=1, radius=0.1, seed=0)
    c = clean(Vh, Fh)
    loops = boundary_loops(c.F)
    small = min(loops, key=len)
    res = fill_holes(c.V, c.F, keep=int(small[0]))  # keep the hole, fill the rim
    assert topology_report(res.V, res.F).boundary_loops == 1
    assert len(boundary_loops(res.F)[0]) == len(small)
    with pytest.raises(Exception, match="keep"):
        fill_holes(c.V, c.F, keep="biggest")
