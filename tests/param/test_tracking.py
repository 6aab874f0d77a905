"""Points of the input mesh carried through intrinsic flips: the actual discrete conformal map."""

import numpy as np
import pytest

from geoface.mesh.core import halfedge_twins
from geoface.param.delaunay import IntrinsicTriangulation
from geoface.param.intrinsic import edge_lengths
from geoface.param.tracking import FlipTracker, scale_bary


def _circumcircle(P):
    a, b, c = P
    d = 2 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]))
    ux = ((a @ a) * (b[1] - c[1]) + (b @ b) * (c[1] - a[1]) + (c @ c) * (a[1] - b[1])) / d
    uy = ((a @ a) * (c[0] - b[0]) + (b @ b) * (a[0] - c[0]) + (c @ c) * (b[0] - a[0])) / d
    o = np.array([ux, uy])
    return o, np.linalg.norm(a - o)


def _layout(l):
    """Triangle with side lengths l (opposite corners 0, 1, 2) in the plane."""
    c = l[2]
    x = (l[1] ** 2 + c**2 - l[0] ** 2) / (2 * c)
    return np.array([[0.0, 0.0], [c, 0.0], [x, np.sqrt(l[1] ** 2 - x**2)]])


def test_vertex_scaling_maps_circumcircle_to_circumcircle():
    # b_i -> b_i exp(-u_i) is the projective map that keeps circumcircles (Springborn 2019)
    l = np.array([1.0, 1.3, 0.9])
    u = np.array([0.4, -0.3, 0.2])
    l2 = l * np.exp(0.5 * (u[[1, 2, 0]] + u[[2, 0, 1]]))
    P, Q = _layout(l), _layout(l2)
    o, r = _circumcircle(P)
    th = np.linspace(0, 2 * np.pi, 17)[:-1]
    pts = o + r * np.stack([np.cos(th), np.sin(th)], 1)
    # barycentrics (outside the triangle too: no clipping here)
    T = np.array([[P[1, 0] - P[0, 0], P[2, 0] - P[0, 0]], [P[1, 1] - P[0, 1], P[2, 1] - P[0, 1]]])
    b12 = np.linalg.solve(T, (pts - P[0]).T).T
    b = np.column_stack([1 - b12.sum(1), b12])
    bb = b * np.exp(-u)
    bb /= bb.sum(1, keepdims=True)
    q = bb @ Q
    o2, r2 = _circumcircle(Q)
    assert np.allclose(np.linalg.norm(q - o2, axis=1), r2, rtol=1e-12)
    # and the wrong sign does not
    bw = b * np.exp(u)
    bw /= bw.sum(1, keepdims=True)
    assert not np.allclose(np.linalg.norm(bw @ Q - o2, axis=1), r2, rtol=1e-3)


def _quad_mesh(D):
    """Triangles (A, B, C) and (B, A, D) with A, B on the x axis, C above, D below."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.4, 0.8, 0.0], [*D, 0.0]])
    F = np.array([[0, 1, 2], [1, 0, 3]])
    return V, F


def _track_quad(V, F, pts_face, pts_bary):
    tri = IntrinsicTriangulation(F, edge_lengths(V, F))
    h = 0  # half-edge A -> B of face 0
    t = int(halfedge_twins(F)[h])
    n = len(V)
    Ls = tri.scaled_halfedges(np.zeros(n))
    tri._flip(h, t, Ls, np.zeros(n), tri.F.ravel().copy(), tri.F[:, [1, 2, 0]].ravel().copy())
    tr = FlipTracker.from_triangulation(tri)
    f, b = tr.track(pts_face, pts_bary)
    return tri, f, b


def test_ptolemy_flip_of_a_cyclic_quad_moves_no_point():
    # on a cyclic quad the Ptolemy length is the Euclidean diagonal: the flip is an
    # isometry and every point must keep its position
    A, B, C = np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.4, 0.8])
    o, r = _circumcircle(np.stack([A, B, C]))
    D = o + r * np.array([np.cos(-1.2), np.sin(-1.2)])
    assert D[1] < 0
    V, F = _quad_mesh(D)
    rng = np.random.default_rng(0)
    bary = rng.dirichlet(np.ones(3), 200)
    face = rng.integers(0, 2, 200)
    pos = np.einsum("ki,kij->kj", bary, V[F[face]])
    tri, f2, b2 = _track_quad(V, F, face, bary)
    assert tri.F.tolist() == [[2, 0, 3], [3, 1, 2]]
    assert np.isclose(tri.L[2], np.linalg.norm(C - D))  # Ptolemy = Euclidean here
    pos2 = np.einsum("ki,kij->kj", b2, V[tri.F[f2]])
    assert np.abs(pos2 - pos).max() < 1e-12


def test_ptolemy_flip_of_a_non_cyclic_quad_is_continuous_and_keeps_vertices():
    V, F = _quad_mesh(np.array([0.7, -0.2]))  # D well inside the circumcircle: non-Delaunay
    # points on the shared edge AB, given from both faces, and the four vertices
    s = np.linspace(0, 1, 11)
    face = np.r_[np.zeros(11, int), np.ones(11, int), [0, 0, 0, 1]]
    bary = np.vstack([np.column_stack([1 - s, s, 0 * s]), np.column_stack([s, 1 - s, 0 * s]), np.eye(3), [[0, 0, 1.0]]])
    tri, f2, b2 = _track_quad(V, F, face, bary)
    # the flipped metric laid out in the plane (lengths of the new triangles)
    L = tri.L.reshape(-1, 3)  # half-edges of (C, A, D), (D, B, C)
    l0 = L[0][[1, 2, 0]]
    X = {}
    P0 = _layout(l0)  # C, A, D
    X[2], X[0], X[3] = P0
    l1 = L[1][[1, 2, 0]]  # D, B, C: place by the shared edge D-C
    P1 = _layout(l1)
    # rigidly move P1 so that its D, C match X[3], X[2]
    def fit(src, dst):
        a = src[1] - src[0]
        b = dst[1] - dst[0]
        th = np.arctan2(b[1], b[0]) - np.arctan2(a[1], a[0])
        R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        return lambda p: (p - src[0]) @ R.T + dst[0]
    # P1's corner 2 (C) must map to X[2] and corner 0 (D) to X[3]; reflect orientation check
    g = fit(np.stack([P1[0], P1[2]]), np.stack([X[3], X[2]]))
    X[1] = g(P1[1])
    Xv = np.array([X[i] for i in range(4)])
    pos = np.einsum("ki,kij->kj", b2, Xv[tri.F[f2]])
    edge_a, edge_b = pos[:11], pos[11:22]
    assert np.abs(edge_a - edge_b).max() < 1e-12  # one point, whichever face it came from
    assert np.allclose(pos[22:], Xv[[0, 1, 2, 3]], atol=1e-12)  # vertices stay vertices
    # the map is not the identity of the old layout (the quad changed shape), but it is
    # monotone along AB
    t = np.linalg.norm(edge_a - Xv[0], axis=1)
    assert np.all(np.diff(t) > 0)


def test_scale_bary_is_normalised():
    F = np.array([[0, 1, 2]])
    b = np.array([[0.2, 0.3, 0.5]])
    out = scale_bary(F, np.array([0]), b, np.array([0.0, np.log(2.0), 0.0]))
    assert np.allclose(out.sum(1), 1) and np.allclose(out, np.array([[0.2, 0.15, 0.5]]) / 0.85)


@pytest.mark.parametrize("seed", [0, 1])
def test_intrinsic_ricci_map_is_continuous_and_fold_free(seed):
    from geoface.param.metrics import map_distortion
    from geoface.param.ricci import ricci_flow_rectangle
    from geoface.synth import irregular_flat_patch

    # an irregular, non-Delaunay flat patch, forced through intrinsic flips
    V, F = irregular_flat_patch(400, seed=seed)
    V = V.copy()
    V[:, 0] *= 1.5  # stretched: non-Delaunay edges
    corners = [int(np.argmin(np.linalg.norm(V[:, :2] - c, axis=1))) for c in ([0, 0], [1.5, 0], [1.5, 1], [0, 1])]
    r = ricci_flow_rectangle(V, F, corners, flips="always")
    assert r.converged and r.intrinsic_flips > 0
    # the flat rectangle maps onto itself, up to the change of discrete conformal class by
    # the Ptolemy flips (measured: aspect 1.497, positions within 0.25 %)
    assert r.aspect == pytest.approx(1.5, rel=0.005)
    # vertices land on their layout positions, edge points agree from both faces
    m = len(r.mesh_F)
    face = np.repeat(np.arange(m), 3)
    assert np.abs(r.map_points(face, np.tile(np.eye(3), (m, 1))) - r.uv[r.mesh_F.ravel()]).max() < 1e-12
    tw = halfedge_twins(r.mesh_F)
    h = np.flatnonzero(tw >= 0)
    k, t = h % 3, tw[h]
    b1 = np.zeros((len(h), 3))
    b1[np.arange(len(h)), k], b1[np.arange(len(h)), (k + 1) % 3] = 0.3, 0.7
    b2 = np.zeros((len(h), 3))
    b2[np.arange(len(h)), t % 3], b2[np.arange(len(h)), (t % 3 + 1) % 3] = 0.7, 0.3
    assert np.abs(r.map_points(h // 3, b1) - r.map_points(t // 3, b2)).max() < 1e-10
    s = map_distortion(r.V, r.mesh_F, r.map_points, level=3).summary()
    assert s["flipped"] == 0
    # the exact map is a similarity; Ptolemy flips change the discrete conformal class a little
    assert s["qc_mean"] < 1.03
    pos = r.map_points(face, np.tile(np.eye(3), (m, 1)))
    assert np.abs(pos / r.width * 1.5 - V[r.mesh_F.ravel(), :2]).max() < 0.01


def test_a_copied_triangulation_flips_on_its_own():
    """``IntrinsicTriangulation.copy`` (the warm start a flow hands the next corner set): equal
    to the original, and flipping the copy leaves the original, its log included, as it was."""
    from geoface.synth import square_grid

    V, F = square_grid(6)
    rng = np.random.default_rng(3)
    V = V + np.column_stack([rng.uniform(-0.05, 0.05, (len(V), 2)), np.zeros(len(V))])
    tri = IntrinsicTriangulation(F, edge_lengths(V, F))
    u = rng.normal(0, 0.6, len(V))
    tri.make_delaunay(u)
    before = {k: (v.copy() if isinstance(v, np.ndarray) else list(v) if isinstance(v, list) else v)
              for k, v in tri.__dict__.items()}
    c = tri.copy()
    assert c.__dict__.keys() == tri.__dict__.keys()
    for k, v in tri.__dict__.items():
        assert (np.array_equal(v, c.__dict__[k]) if isinstance(v, np.ndarray) else v == c.__dict__[k]), k
    assert c.make_delaunay(-3 * u) > 0  # another metric: the copy flips
    for k, v in before.items():
        now = tri.__dict__[k]
        assert (np.array_equal(v, now) if isinstance(v, np.ndarray) else v == now), k
