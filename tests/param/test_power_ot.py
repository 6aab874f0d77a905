"""Power diagrams, semi-discrete OT and the measure-preserving map."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geoface.errors import ParameterizationError
from geoface.param.measure import measure_preserving_map, signed_uv_areas
from geoface.param.ot import semi_discrete_ot, transport_hessian
from geoface.param.power import power_diagram


def brute_force_cells(P, w, res=700):
    """Areas and centroids by assigning a fine grid of sample points to the lowest power."""
    g = (np.arange(res) + 0.5) / res
    S = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    # lowest power |s - p|^2 - w = nearest site after lifting p to (p, sqrt(max w - w)) and
    # s to (s, 0): an exact k-d tree query instead of a dense argmin
    from scipy.spatial import cKDTree
    lift = np.sqrt(np.max(w) - w)
    _, own = cKDTree(np.column_stack([P, lift])).query(np.column_stack([S, np.zeros(len(S))]))
    cnt = np.bincount(own, minlength=len(P))
    cx = np.bincount(own, S[:, 0], len(P)) / np.maximum(cnt, 1)
    cy = np.bincount(own, S[:, 1], len(P)) / np.maximum(cnt, 1)
    return cnt / len(S), np.column_stack([cx, cy])


def grid_points(k):
    g = (np.arange(k) + 0.5) / k
    return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)


def test_uniform_grid_equal_cells_centroids_at_points():
    P = grid_points(9)
    pd = power_diagram(P)
    assert np.allclose(pd.area, 1 / 81, rtol=1e-12)
    assert np.abs(pd.centroid - P).max() < 1e-12
    # every interior site has 4 neighbours with shared edge 1/9
    assert np.allclose(pd.edge_length, 1 / 9)
    assert len(pd.edges) == 2 * 9 * 8
    ot = semi_discrete_ot(P)
    assert ot.converged and ot.iterations == 0
    assert np.abs(ot.h).max() < 1e-12
    assert np.abs(ot.centroid - P).max() < 1e-12


def test_power_cells_match_brute_force():
    rng = np.random.default_rng(3)
    P = rng.random((60, 2))
    w = rng.random(60) * 0.004
    pd = power_diagram(P, w)
    a, c = brute_force_cells(P, w)
    assert abs(pd.area.sum() - 1) < 1e-12
    assert np.abs(pd.area - a).max() < 2e-3  # sampling error of a 700^2 grid
    big = pd.area > 5e-3
    assert np.abs(pd.centroid[big] - c[big]).max() < 3e-3
    assert ((pd.area == 0) == (a == 0)).mean() > 0.95


@pytest.mark.parametrize("backend,layout", [("cgal", "random"), ("cgal", "grid"), ("cgal", "clustered"),
                                            ("qhull", "random"), ("qhull", "grid")])
def test_flip_update_equals_fresh_hull(backend, layout):
    """A diagram updated by edge flips from the previous weights' triangulation (compiled with
    exact predicates for CGAL, NumPy rounds for Qhull) is the diagram built from scratch
    (CGAL's exact regular triangulation): same cells, same shared edges, same triangles."""
    from geoface.param import regular

    if backend == "cgal" and not regular.available():
        pytest.skip("CGAL extension not built")
    rng = np.random.default_rng(7)
    if layout == "random":
        P = rng.random((2000, 2))
    elif layout == "grid":
        P = grid_points(40)  # cocircular quads everywhere
    else:
        P = np.concatenate([rng.random((1000, 2)), 0.3 + 1e-6 * rng.random((500, 2))])
    n = len(P)
    pd0 = power_diagram(P, backend=backend)
    # weight changes on the scale of each site's squared spacing: the triangulation changes
    # a lot while no cell vanishes
    nn = cKDTree(P).query(P, 2)[0][:, 1]
    updated = 0
    for scale in (0.05, 0.2, 0.4):
        w1 = scale * nn**2 * rng.normal(0, 1, n)
        a = power_diagram(P, w1, previous=pd0, backend=backend)
        b = power_diagram(P, w1, backend="cgal")
        updated += a.source == "flips"
        assert b.source == "cgal"
        if a.source == "flips" and backend == "cgal":  # a proper triangulation: no edge merging needed
            assert len(np.unique(a.edges, axis=0)) == len(a.edges)
        if backend == "cgal" and layout == "random" and a.source == "flips":  # no ties: the same triangles
            key = lambda T: {tuple(np.roll(t, -int(np.argmin(t)))) for t in T}  # noqa: E731
            assert key(a._tri.T) == key(b._tri.T)
        # round-off only: a wrong edge would change areas by a share of a cell
        assert np.abs(a.area - b.area).max() < 1e-10 / n
        big = a.edge_length > 1e-9
        ea = set(map(tuple, a.edges[big].tolist()))
        eb = set(map(tuple, b.edges[b.edge_length > 1e-9].tolist()))
        assert len(ea ^ eb) <= 2  # dual edges of length ~1e-9 may sit on either side of the cut
        assert np.abs(a.centroid - b.centroid).max() < 1e-9
        assert (len(set(map(tuple, a.edges.tolist())) ^ set(map(tuple, pd0.edges.tolist()))) > 0) or layout == "grid"
    assert updated >= 2


@pytest.mark.parametrize("layout", ["random", "grid", "clustered", "outside"])
def test_compiled_cells_are_the_numpy_cells(layout, monkeypatch):
    """The compiled cell sums and power centres (CGAL extension) give the NumPy path's
    areas, centroids and shared edges to round-off, on sites inside, on and outside the square."""
    from geoface.param import power, regular
    from geoface.param.power_triangulation import _orient, _power_centres

    if not regular.available() or regular.power_cells(1, np.zeros((1, 2)), np.zeros((0, 3)), np.zeros((0, 3)),
                                                      np.zeros((0, 2))) is None:
        pytest.skip("geoface's CGAL extension is not built")
    rng = np.random.default_rng(11)
    if layout == "random":
        P = rng.random((3000, 2))
    elif layout == "grid":
        P = grid_points(30)
    elif layout == "clustered":
        P = np.concatenate([rng.random((1000, 2)), 0.3 + 1e-6 * rng.random((300, 2))])
    else:
        P = rng.random((500, 2)) * 1.4 - 0.2
    nn = cKDTree(P).query(P, 2)[0][:, 1]
    w = 0.3 * nn**2 * rng.normal(0, 1, len(P))
    a = power_diagram(P, w, backend="cgal")
    monkeypatch.setattr(power, "COMPILED_CELLS", False)
    b = power_diagram(P, w, backend="cgal")
    assert abs(a.area.sum() - 1) < 1e-12
    assert np.abs(a.area - b.area).max() < 1e-15
    assert np.abs(a.centroid - b.centroid).max() < 1e-12
    assert np.array_equal(a.edges, b.edges) and np.abs(a.edge_length - b.edge_length).max() < 1e-14
    # CGAL's triangulation has each pair of sites once: the edges need no merging
    assert len(np.unique(a.edges, axis=0)) == len(a.edges) and (a.edges[:, 0] < a.edges[:, 1]).all()
    # power centres of arbitrary triangles, flat and clockwise ones included
    X = rng.random((200, 2))
    X[7] = X[3]  # a repeated vertex: a flat triangle
    wa = rng.normal(0, 1e-3, 200)
    T = rng.integers(0, 200, (1000, 3))
    T[0] = [3, 7, 9]
    cen, flat = regular.power_centres(X, wa, T)
    with np.errstate(divide="ignore", invalid="ignore"):
        ref = _power_centres(X, wa, T)
        o = _orient(X, T[:, 0], T[:, 1], T[:, 2])
    ok = np.isfinite(ref).all(1)
    assert np.array_equal(np.isfinite(cen).all(1), ok) and not ok[0]
    assert np.abs(cen[ok] - ref[ok]).max() < 1e-12 * max(1.0, np.abs(ref[ok]).max())
    assert flat == int((o <= 0).sum()) > 400


def test_exact_flips_and_new_triangulations_give_the_same_solve(monkeypatch):
    """OT's trial diagrams come from flips of the last accepted one (compiled, exact): the
    same steps and heights as building every diagram anew, and the flips are taken."""
    from geoface.param import power, regular

    if not regular.available():
        pytest.skip("CGAL extension not built")
    rng = np.random.default_rng(3)
    P = np.concatenate([rng.random((1500, 2)), 0.6 + 1e-6 * rng.random((30, 2))])
    nu = rng.random(len(P)) + 0.5
    sources = []
    real = power.power_diagram

    def spy(*a, **k):
        pd = real(*a, **k)
        sources.append(pd.source)
        return pd

    monkeypatch.setattr("geoface.param.ot.power_diagram", spy)
    r_flip = semi_discrete_ot(P, nu, tol=1e-8)
    assert sources.count("flips") >= r_flip.iterations - 1
    monkeypatch.setattr(power, "EXACT_FLIPS", False)
    sources.clear()
    r_new = semi_discrete_ot(P, nu, tol=1e-8)
    assert "flips" not in sources
    assert r_new.iterations == r_flip.iterations and r_flip.residual <= 1e-8
    assert np.abs(r_new.h - r_flip.h).max() < 1e-12


def test_bare_exact_flips():
    """regular.flip_to_regular: the regular triangulation of the new weights (CGAL's own, triangle
    for triangle), neighbours consistent; None when a site must vanish or flips run out."""
    from geoface.param import regular

    if not regular.available():
        pytest.skip("CGAL extension not built")
    rng = np.random.default_rng(11)
    X = np.concatenate([rng.random((800, 2)), [[9.0, 0.0], [0.0, 9.0], [-9.0, 0.0], [0.0, -9.0]]])
    T0, N0 = regular.regular_triangulation(X, np.zeros(len(X)))
    w = 0.3 * cKDTree(X).query(X, 2)[0][:, 1] ** 2 * rng.normal(0, 1, len(X))
    w[-4:] = 0.0
    T1, _ = regular.regular_triangulation(X, w)
    assert len(np.unique(T1)) == len(X)
    T, N, k = regular.flip_to_regular(X, w, T0, N0)
    assert k > 50 and np.array_equal(T0, regular.regular_triangulation(X, np.zeros(len(X)))[0])  # inputs untouched
    key = lambda T: {tuple(np.roll(t, -int(np.argmin(t)))) for t in T}  # noqa: E731
    assert key(T) == key(T1)
    m = len(T)
    for t in range(m):  # each neighbour shares the edge opposite the vertex, and points back
        for j in range(3):
            s = N[t, j]
            if s >= 0:
                assert t in N[s] and set(T[t]) - {T[t, j]} <= set(T[s])
    assert regular.flip_to_regular(X, w, T0, N0, max_flips=k - 1) is None
    w2 = w.copy()
    w2[100] = -1.0  # its cell vanishes: flips cannot remove a vertex
    assert regular.flip_to_regular(X, w2, T0, N0) is None


def test_flip_update_falls_back_when_a_cell_vanishes():
    """A site whose weight drops until its cell is empty cannot be reached by flips: the
    update gives up and the diagram is built anew (exactly)."""
    P = grid_points(6)
    pd0 = power_diagram(P)
    w = np.zeros(len(P))
    w[14] = -1.0  # far below its neighbours: its cell disappears
    a = power_diagram(P, w, previous=pd0)
    assert a.source == "cgal" and a.area[14] == 0
    b = power_diagram(P, w)
    assert np.allclose(a.area, b.area, atol=1e-15)


def test_flip_update_needs_the_same_points():
    rng = np.random.default_rng(0)
    P = rng.random((200, 2))
    pd0 = power_diagram(P)
    a = power_diagram(P + 1e-3, None, previous=pd0)
    assert a.source == "cgal"


@pytest.mark.parametrize("layout", ["random", "grid"])
def test_qhull_and_cgal_agree_on_well_separated_sites(layout):
    rng = np.random.default_rng(5)
    P = rng.random((1500, 2)) if layout == "random" else grid_points(30)
    w = 0.1 * cKDTree(P).query(P, 2)[0][:, 1] ** 2 * rng.normal(0, 1, len(P))
    a = power_diagram(P, w, backend="qhull")
    b = power_diagram(P, w, backend="cgal")
    assert a.source == "qhull" and b.source == "cgal"
    assert np.abs(a.area - b.area).max() < 1e-12
    assert np.abs(a.centroid - b.centroid).max() < 1e-9


def test_presorted_insertion_is_the_same_triangulation():
    """CGAL's triangulation with the spatial order sorted once (a Newton solve's sites do not
    move) has the same triangles as its own range insertion — with hidden sites, a crowded
    cluster and duplicates — and power_diagram hands the order on to the next diagram."""
    from geoface.param import regular

    if not regular.available():
        pytest.skip("CGAL extension not built")
    rng = np.random.default_rng(8)
    X = np.concatenate([rng.random((2000, 2)), 0.3 + 1e-9 * rng.random((50, 2)), rng.random((5, 2))])
    X = np.concatenate([X, X[-5:]])  # five duplicates
    w = 1e-4 * rng.normal(0, 1, len(X))  # enough to hide some sites
    order = regular.spatial_order(X, first=[3, 1])
    assert order is not None and np.array_equal(np.sort(order), np.arange(len(X))) and list(order[:2]) == [3, 1]
    T0, _ = regular.regular_triangulation(X, w)
    T1, N1 = regular.regular_triangulation(X, w, order)
    assert len(np.unique(T0)) < len(X) - 100  # hidden sites are absent
    key = lambda T: {tuple(np.roll(t, -int(np.argmin(t)))) for t in T}  # noqa: E731
    assert key(T0) == key(T1)
    m = len(T1)
    back = N1 >= 0  # neighbours point back
    assert ((N1[back] < m) & (N1[N1[back]] == np.repeat(np.arange(m), 3).reshape(m, 3)[back][:, None]).any(1)).all()
    with pytest.raises(ParameterizationError, match="order"):
        regular.regular_triangulation(X, w, order[:-1])
    P = rng.random((500, 2))
    a = power_diagram(P, backend="cgal")
    w = 1e-4 * rng.normal(0, 1, 500)
    with pytest.MonkeyPatch.context() as mp:  # built anew: the previous diagram lends its order only
        mp.setattr("geoface.param.power.EXACT_FLIPS", False)
        b = power_diagram(P, w, previous=a, backend="cgal")
    assert b._tri.order is a._tri.order and b.source == "cgal"
    fresh = power_diagram(P, w, backend="cgal")  # sorts anew: the same cells
    assert fresh._tri.order is not a._tri.order
    assert np.abs(b.area - fresh.area).max() < 1e-15 and np.abs(b.centroid - fresh.centroid).max() < 1e-12


@pytest.mark.parametrize("spacing", [1e-6, 1e-9, 1e-11])
def test_exact_predicates_resolve_crowded_sites(spacing):
    """Sites far closer than floating point resolves by arithmetic (the squeezed ends of
    conformal maps of real scans) each keep their own Voronoi cell: the areas of a
    cluster's cells add up to the area a single site there would own, and each cell holds
    its site."""
    rng = np.random.default_rng(4)
    base = rng.random((300, 2))
    cluster = 0.41 + spacing * rng.random((200, 2))
    P = np.concatenate([base, cluster])
    pd = power_diagram(P, backend="cgal")
    assert (pd.area > 0).all()
    one = power_diagram(np.concatenate([base, [[0.41 + spacing / 2] * 2]]), backend="cgal")
    # the cluster as a whole owns what one site at its centre owns (up to its own size)
    assert abs(pd.area[300:].sum() - one.area[300]) < 1e-6 * one.area[300] + 10 * spacing
    assert np.allclose(pd.area[:300], one.area[:300], atol=10 * spacing)
    # Qhull cannot: it merges most of the cluster
    if spacing <= 1e-9:
        assert (power_diagram(P, backend="qhull").area[300:] == 0).sum() > 100


def test_hessian_matches_finite_differences():
    rng = np.random.default_rng(1)
    P = rng.random((40, 2))
    h = rng.random(40) * 1e-3
    pd = power_diagram(P, h)
    H = transport_hessian(P, pd).toarray()
    eps = 1e-7
    for j in (0, 7, 21):
        hp = h.copy(); hp[j] += eps
        hm = h.copy(); hm[j] -= eps
        col = (power_diagram(P, hp).area - power_diagram(P, hm).area) / (2 * eps)
        assert np.abs(col - H[:, j]).max() < 1e-4 * max(1.0, np.abs(H[:, j]).max())
    assert np.allclose(H.sum(1), 0, atol=1e-9)


def test_nonuniform_target_met():
    rng = np.random.default_rng(0)
    P = rng.random((3000, 2))
    nu = rng.uniform(0.2, 5.0, 3000)
    ot = semi_discrete_ot(P, nu, tol=1e-3)
    assert ot.converged
    nu = nu / nu.sum()
    assert np.max(np.abs(ot.area - nu) / nu) <= 1e-3
    # independent check of the final diagram
    a, _ = brute_force_cells(P, ot.h, res=600)
    assert np.abs(a - nu).sum() < 0.02
    assert abs(ot.h.sum()) < 1e-9


@pytest.mark.parametrize("layout", ["random", "crowded"])
def test_inexact_newton_reuses_factorisations(layout, monkeypatch):
    """Newton directions by conjugate gradients preconditioned with an earlier factorisation
    meet the same tolerance as exact Newton (a factorisation every step), with fewer
    factorisations than steps, also where sites crowd 1e-6 apart (their differences need the
    Hessian applied to differences)."""
    from geoface.param import ot as ot_mod

    rng = np.random.default_rng(5)
    if layout == "random":
        P = rng.random((3000, 2))
        nu = rng.uniform(0.2, 5.0, 3000)
    else:
        P = np.concatenate([rng.random((1500, 2)), 0.5 + 1e-6 * rng.random((100, 2))])
        nu = np.r_[np.ones(1500), np.full(100, 4.0)]
    inexact = semi_discrete_ot(P, nu, tol=1e-6)
    monkeypatch.setattr(ot_mod, "REUSE_FACTOR", False)
    exact = semi_discrete_ot(P, nu, tol=1e-6)
    assert exact.factorizations == exact.iterations and exact.pcg_iterations == 0
    assert inexact.converged and inexact.residual <= 1e-6
    assert inexact.pcg_iterations > 0 and inexact.factorizations < inexact.iterations
    assert np.abs(inexact.area - exact.area).max() <= 2e-6 * exact.nu.max()
    assert np.abs(inexact.centroid - exact.centroid).max() < 1e-6


def test_clustered_points_with_huge_mass_ratio():
    """A cluster 1e-3 wide (1e-6 of the area) must grow to hold half the square, as the
    face does in conformal maps of heads."""
    rng = np.random.default_rng(2)
    P = np.concatenate([rng.random((400, 2)), 0.5 + 1e-3 * rng.random((100, 2))])
    nu = np.concatenate([np.full(400, 1.0), np.full(100, 4.0)])
    ot = semi_discrete_ot(P, nu, tol=1e-3)
    assert ot.converged and ot.residual <= 1e-3
    assert (ot.area > 0).all() and ot.stages > 1


@pytest.mark.parametrize("size", [1e-4, 1e-6])
def test_crowded_sites_each_get_their_mass(size):
    """A cluster of 100 random sites in a box 1e-6 wide (1e-12 of the area; closest pairs
    ~1e-8 apart) must grow to hold 4/9 of the square, each site its own share: exact
    predicates keep every site (Qhull merges them)."""
    spacing = size
    rng = np.random.default_rng(2)
    P = np.concatenate([rng.random((400, 2)), 0.5 + spacing * rng.random((100, 2))])
    nu = np.r_[np.ones(400), np.full(100, 4.0)]
    ot = semi_discrete_ot(P, nu, backend="cgal")
    assert ot.converged and ot.merged == 0 and ot.backend == "cgal"
    assert np.max(np.abs(ot.area - ot.nu) / ot.nu) <= 1e-3
    assert len(np.unique(ot.centroid[400:], axis=0)) == 100


def test_beyond_double_precision_is_a_clear_error():
    """Random sites 1e-10 apart whose cells must grow 1e18-fold need heights resolved to
    ~1e-25: a ParameterizationError, never a crash or a wrong answer."""
    rng = np.random.default_rng(2)
    P = np.concatenate([rng.random((400, 2)), 0.5 + 1e-9 * rng.random((100, 2))])
    nu = np.r_[np.ones(400), np.full(100, 4.0)]
    try:
        ot = semi_discrete_ot(P, nu, backend="cgal", max_iterations=60)
    except ParameterizationError:
        return
    assert not ot.converged or np.max(np.abs(ot.area - ot.nu) / ot.nu) <= 1e-3


def test_sites_below_qhull_resolution_share_cells():
    """With Qhull (no CGAL), sites 1e-7 apart are beyond its resolution: they are merged with
    the site that owns their position, the merged masses are met, and merged sites share a
    centroid."""
    rng = np.random.default_rng(2)
    P = np.concatenate([rng.random((400, 2)), 0.5 + 1e-7 * rng.random((100, 2))])
    nu = np.r_[np.ones(400), np.full(100, 4.0)]
    ot = semi_discrete_ot(P, nu, max_iterations=50, backend="qhull")
    assert ot.converged and ot.merged > 0
    cluster = ot.centroid[400:]
    assert len(np.unique(cluster, axis=0)) == 100 - ot.merged
    assert abs(ot.area[400:].sum() - nu[400:].sum() / nu.sum()) < 1e-3 * nu[400:].sum() / nu.sum()


def test_duplicates_and_edge_points_do_not_crash():
    P = np.array([[0, 0], [0, 0], [1, 1], [0.5, 0], [0.5, 0.5], [0.5, 0.5], [1, 0.3], [0.2, 1.0], [0.7, 0.7]], float)
    pd = power_diagram(P)
    assert abs(pd.area.sum() - 1) < 1e-12 and (pd.area >= 0).all()
    assert (pd.area == 0).sum() == 2  # one of each coincident pair
    ot = semi_discrete_ot(P)
    assert ot.converged and ot.merged == 2
    # coincident sites share a cell: their masses add up and their centroids agree
    assert np.allclose(ot.centroid[0], ot.centroid[1]) and np.allclose(ot.centroid[4], ot.centroid[5])
    assert abs(ot.area[0] + ot.area[1] - 2 / 9) < 1e-3 * 2 / 9


@pytest.mark.parametrize("bad", [np.full((5, 2), np.nan), np.zeros((5, 3)), np.array([[0.1, 0.1], [5.0, 0.2]])])
def test_bad_points_raise(bad):
    with pytest.raises(ParameterizationError):
        power_diagram(bad)


def test_bad_masses_raise():
    P = grid_points(3)
    with pytest.raises(ParameterizationError):
        semi_discrete_ot(P, np.r_[np.ones(8), -1.0])
    with pytest.raises(ParameterizationError):
        semi_discrete_ot(P, np.ones(4))


def test_measure_preserving_map_on_flat_square_is_identity():
    from geoface.synth import square_grid

    V, F = square_grid(12)
    uv = V[:, :2]
    # interior vertices: 1/3 of adjacent areas are equal -> cells centred on the vertices
    m = measure_preserving_map(V, F, uv, roi=None)
    assert m.flipped_after == 0
    inner = (uv > 0).all(1) & (uv < 1).all(1)
    # boundary cells are half-size, so the map moves the vertices next to them a little;
    # the map stays close to the identity and exactly on the boundary
    assert np.abs(m.uv - uv).max() < 0.05
    b = ~inner
    assert np.allclose(np.minimum(np.minimum(m.uv[b], 1 - m.uv[b]).min(1), 1), 0, atol=1e-12)


@pytest.fixture(scope="module")
def head_map():
    from geoface.param.ricci import ricci_flow_rectangle
    from geoface.synth.head import procedural_head

    h = procedural_head(6000, seed=1)
    r = ricci_flow_rectangle(h.V, h.F)
    return h, r


@pytest.mark.parametrize("lam", [1.0, 2.5])
def test_measure_preserving_head(head_map, lam):
    from geoface.param.metrics import distortion

    h, r = head_map
    m = measure_preserving_map(h.V, r.F, r.unit_square(), roi=h.face_mask, lam=lam)
    assert m.ot.converged and m.ot.residual <= 1e-3
    assert m.flipped_after == 0
    assert (signed_uv_areas(r.F, m.uv) > 0).all() or (signed_uv_areas(r.F, m.uv) < 0).all()
    d = distortion(h.V, r.F, m.uv).summary()
    assert d["flipped"] == 0
    face_share_3d = (np.abs(np.cross(*(h.V[r.F][:, 1:] - h.V[r.F][:, :1]).transpose(1, 0, 2))) ** 2).sum(1) ** 0.5
    in_roi = h.face_mask[r.F].all(1)
    a = face_share_3d[in_roi].sum() / face_share_3d.sum()
    expect = lam * a / (1 + (lam - 1) * a)
    assert abs(m.roi_share - expect) < 0.03
    if lam == 1.0:
        assert d["log_area_abs_mean"] <= 0.1


def test_solver_keeps_set_up_and_warm_starts_a_lam_sweep(head_map):
    """MeasurePreservingSolver: the same map as the function, and a second solve from the same
    starting map (another lam) starts OT from the first one's heights: the same result within
    the tolerance in far fewer Newton steps (ICT head, 12K vertices: 12 steps cold, 2 warm)."""
    from geoface.param.measure import MeasurePreservingSolver

    h, r = head_map
    uv = r.unit_square()
    once = measure_preserving_map(h.V, r.F, uv, roi=h.face_mask, lam=3.0)
    solver = MeasurePreservingSolver(h.V, r.F)
    first = solver.solve(uv, roi=h.face_mask, lam=2.5)
    assert not solver.warm_started and first.converged
    warm = solver.solve(uv, roi=h.face_mask, lam=3.0)
    assert solver.warm_started and warm.converged and warm.flipped_after == 0
    assert warm.ot.iterations < once.ot.iterations
    assert abs(warm.roi_share - once.roi_share) < 2e-3 and np.abs(warm.uv - once.uv).max() < 0.02
    other = solver.solve(np.column_stack([1 - uv[:, 0], uv[:, 1]]), roi=h.face_mask, lam=3.0)  # another start: cold
    assert not solver.warm_started and other.converged
    with pytest.raises(AttributeError):
        warm.residual = 0.0  # results are frozen


def _anisotropy(V, F, uv) -> np.ndarray:
    """Per-triangle ratio of the map's singular values (1 = conformal)."""
    P, Q = V[F], uv[F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    n = np.cross(e1, e2)
    x = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    y = np.cross(n / np.linalg.norm(n, axis=1, keepdims=True), x)
    A = np.stack([np.stack([(e1 * x).sum(1), (e2 * x).sum(1)], 1), np.stack([(e1 * y).sum(1), (e2 * y).sum(1)], 1)], 1)
    B = np.stack([Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]], 2)
    s = np.linalg.svd(B @ np.linalg.inv(A), compute_uv=False)
    return s[:, 0] / s[:, 1]


def test_blend_masses_mix_the_logs_of_both_areas(head_map):
    from geoface.mesh.core import vertex_areas
    from geoface.param.measure import MeasurePreservingSolver

    h, r = head_map
    uv = r.unit_square()
    s = MeasurePreservingSolver(h.V, r.F)
    plain = s.masses(h.face_mask, 2.5)
    assert np.array_equal(s.masses(h.face_mask, 2.5, uv=uv, blend=0.0), plain)
    mixed = s.masses(h.face_mask, 2.5, uv=uv, blend=0.3)
    assert np.isclose(mixed.sum(), plain.sum())
    ua = vertex_areas(np.column_stack([uv, np.zeros(len(uv))]), r.F)
    d = np.log(mixed) - (0.7 * np.log(plain) + 0.3 * np.log(ua))
    assert np.ptp(d) < 1e-9  # the same up to the normalising constant
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ParameterizationError):
            s.masses(h.face_mask, 2.5, uv=uv, blend=bad)
    with pytest.raises(ParameterizationError):
        s.masses(h.face_mask, 2.5, blend=0.2)  # needs the starting map


def test_blend_keeps_the_band_at_the_cut_wide(head_map):
    """The area-preserving map squeezes the triangles along the cut (the neck opening mapped
    onto the whole perimeter) into long thin ones: on this head the 95th percentile of their
    singular-value ratio is ~200 at blend 0 and ~29 at 0.2.  The blended map meets its own
    masses (converged, fold-free) and gives the face less of the square, but not much less."""
    from geoface.mesh.core import boundary_loops

    h, r = head_map
    uv = r.unit_square()
    near = np.isin(r.F, np.concatenate(boundary_loops(r.F))).any(1)
    p95 = {}
    share = {}
    for beta in (0.0, 0.2):
        m = measure_preserving_map(h.V, r.F, uv, roi=h.face_mask, lam=2.5, blend=beta)
        assert m.converged and m.flipped_after == 0
        p95[beta] = np.percentile(_anisotropy(h.V, r.F, m.uv)[near], 95)
        share[beta] = m.roi_share
    assert p95[0.2] < p95[0.0] / 4
    assert 0.7 * share[0.0] < share[0.2] < share[0.0]


def test_the_solver_refuses_arguments_that_cannot_be_solved(head_map):
    """Every argument checked where it enters: a tolerance that is not one, an unknown backend or
    linear solver, a closed surface, a mass factor beyond what the linear solves hold (1e300 once
    reached CHOLMOD), a NaN or fractional ROI, heights of the wrong shape or NaN."""
    from geoface.param.measure import MeasurePreservingSolver
    from geoface.synth import sphere

    h, r = head_map
    uv = r.unit_square()
    for kw in ({"tol": float("nan")}, {"tol": 0}, {"tol": -1}, {"backend": "bogus"}, {"linear_solver": "x"}):
        with pytest.raises(ParameterizationError, match=next(iter(kw))):
            MeasurePreservingSolver(h.V, r.F, **kw)
    with pytest.raises(ParameterizationError, match="closed surface"):
        MeasurePreservingSolver(*sphere(1.0, 2))
    solver = MeasurePreservingSolver(h.V, r.F)
    n = len(h.V)
    bad_roi = np.where(h.face_mask, 1.0, np.nan)
    for kw, what in (({"lam": 1e300}, "lam"), ({"roi": bad_roi}, "roi"), ({"roi": np.full(n, 0.5)}, "roi"),
                     ({"h0": np.zeros(3)}, "h0"), ({"h0": np.full(n, np.nan)}, "h0")):
        with pytest.raises(ParameterizationError, match=what):
            solver.solve(uv, **kw)


@pytest.mark.parametrize("method", ["cholmod", "splu"])
def test_a_failed_factorisation_is_a_parameterization_error(method):
    """CHOLMOD's NotPositiveDefiniteError and SuperLU's singular factor reach callers as
    ParameterizationError (a GeofaceError: one line at the command line), not as the library's own."""
    import scipy.sparse as sp

    from geoface.param.linsolve import SPDSolver, cholmod_available

    if method == "cholmod" and not cholmod_available():
        pytest.skip("scikit-sparse is not installed")
    bad = sp.csc_matrix(np.array([[1.0, 2.0], [2.0, 1.0]])) if method == "cholmod" else sp.csc_matrix((2, 2))
    with pytest.raises(ParameterizationError, match="factorisation failed"):
        SPDSolver(method).solve(bad, np.ones(2))
    good = sp.csc_matrix(np.array([[2.0, 1.0], [1.0, 2.0]]))
    np.testing.assert_allclose(SPDSolver(method).solve(good, np.ones(2)), [1 / 3, 1 / 3])
