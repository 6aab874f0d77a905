"""make_disk on everything users bring: real messy meshes, analytic surfaces of every
topology, and procedural heads with holes punched in."""

import numpy as np
import pytest

from geoface.errors import InvalidMeshError, MeshTopologyError
from geoface.mesh import topology_report
from geoface.mesh.core import face_areas
from geoface.mesh.io import load_mesh
from geoface.repair import RepairOptions, make_disk
from geoface.synth import cylinder, genus2, hemisphere, mobius_strip, sphere, torus
from tests.helpers import shared_mesh


def assert_disk(res):
    r = topology_report(res.V, res.F)
    assert r.is_disk, r.format()
    assert r.components == 1 and r.manifold and r.consistently_oriented
    assert r.genus == 0 and r.boundary_loops == 1 and r.degenerate_faces == 0
    assert r.duplicate_vertices == 0
    assert res.report == r
    assert len(res.vertex_map) == len(res.V) and len(res.face_map) == len(res.F)
    return r


def assert_idempotent(res, **kw):
    again = make_disk(res.V, res.F, **kw)
    assert again.changes == []
    assert np.array_equal(again.V, res.V) and np.array_equal(again.F, res.F)


# (file, up axis, bound on |area change| / area)
REAL = [("beetle.obj", "y", 0.25), ("spot.obj", "y", 0.02), ("ninjaHead_Low.obj", "y", 0.0)]


@pytest.mark.parametrize("name, up, area_bound", REAL)
def test_real_meshes(name, up, area_bound):
    m = load_mesh(shared_mesh(name))
    res = make_disk(m.V, m.F, up=up)
    assert_disk(res)
    assert_idempotent(res, up=up)
    assert abs(res.area_after - res.area_before) <= area_bound * res.area_before + 1e-12
    # provenance: mapped vertices sit where they were, except copies of split
    # (non-manifold) vertices, which moved by the small separation only
    ok = res.vertex_map >= 0
    d = np.linalg.norm(res.V[ok] - m.V[res.vertex_map[ok]], axis=1)
    assert (d > 0).mean() < 0.05
    assert d.max() < 0.05 * res.report.bbox_diagonal


def test_ninja_head_is_already_a_disk():
    m = load_mesh(shared_mesh("ninjaHead_Low.obj"))
    res = make_disk(m.V, m.F)
    assert res.changes == []
    assert np.array_equal(res.V, m.V) and np.array_equal(res.F, m.F)
    assert np.array_equal(res.vertex_map, np.arange(len(m.V)))


def test_beetle_nonmanifold_and_components_reported():
    m = load_mesh(shared_mesh("beetle.obj"))
    before = topology_report(m.V, m.F)
    assert before.nonmanifold_edges > 0 and before.components > 1
    res = make_disk(m.V, m.F)
    steps = {c["step"] for c in res.changes}
    assert {"split_nonmanifold_edges", "remove_components", "fill_hole"} <= steps


def test_spot_is_opened_at_the_bottom():
    m = load_mesh(shared_mesh("spot.obj"))
    res = make_disk(m.V, m.F, up="y")
    cut = [c for c in res.changes if c["step"] == "open_plane"]
    assert len(cut) == 1
    h = m.V[:, 1]
    assert cut[0]["origin"][1] == pytest.approx(h.min() + 0.02 * (h.max() - h.min()))


@pytest.mark.parametrize(
    "make, area_bound",
    [
        (lambda: torus(1.0, 0.3, 48, 24), 0.25),
        (lambda: genus2(48), 0.25),
        (lambda: sphere(1.0, 3), 0.05),
        (lambda: cylinder(1.0, 2.0, 32, 16), 0.35),
        (lambda: hemisphere(1.0, 10), 0.0),
        (lambda: mobius_strip(), 0.01),
    ],
)
def test_analytic_surfaces(make, area_bound):
    V, F = make()
    res = make_disk(V, F, up="z")
    assert_disk(res)
    assert_idempotent(res, up="z")
    assert abs(res.area_after - res.area_before) <= area_bound * res.area_before + 1e-12


def test_cap_opening_and_none():
    V, F = sphere(1.0, 3)
    res = make_disk(V, F, open="cap", up="z", cap_area=0.05)
    assert_disk(res)
    assert res.area_after == pytest.approx(0.95 * res.area_before, rel=0.02)
    with pytest.raises(MeshTopologyError, match="closed"):
        make_disk(V, F, open="none")


def test_bad_input_and_options():
    V, F = sphere(1.0, 1)
    with pytest.raises(InvalidMeshError, match="NaN"):
        make_disk(np.where(np.arange(len(V))[:, None] == 3, np.nan, V), F)
    with pytest.raises(InvalidMeshError, match="indexes"):
        make_disk(V, F + 1000)
    with pytest.raises(InvalidMeshError, match="open must be"):
        make_disk(V, F, open="sideways")
    with pytest.raises(InvalidMeshError, match="up"):
        make_disk(V, F, up="q")
    with pytest.raises(TypeError):
        make_disk(V, F, not_an_option=1)


def test_options_object_and_remesh():
    V, F = torus(1.0, 0.3, 64, 32)  # 2048 vertices
    opts = RepairOptions(up="z", target_vertices=600)
    res = make_disk(V, F, opts)
    assert_disk(res)
    assert 450 < len(res.V) < 800
    assert res.changes[0]["step"] == "remesh"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_procedural_heads_with_random_holes(seed):
    from geoface.synth import procedural_head, punch_holes

    head = procedural_head(n_vertices=6000, seed=seed)
    V, F = punch_holes(head.V, head.F, n_holes=4, radius=0.04, seed=seed)
    res = make_disk(V, F)
    r = assert_disk(res)
    assert_idempotent(res)
    # the neck (the longest loop) stays the boundary: same length as before
    neck = topology_report(head.V, head.F).boundary_loop_lengths[0]
    assert r.boundary_loop_lengths[0] == pytest.approx(neck, rel=1e-12)
    # the faired patches restore the missing skin closely
    assert res.area_after == pytest.approx(face_areas(head.V, head.F).sum(), rel=0.02)
    assert sum(c["step"] == "fill_hole" for c in res.changes) >= 2
    # untouched vertices are exactly where they were
    ok = res.vertex_map >= 0
    assert np.array_equal(res.V[ok], V[res.vertex_map[ok]])


def _messy(n, seed, closed):
    import sys

    from tests.helpers import REPO

    sys.path.insert(0, str(REPO / "data_tools"))
    from make_messy_head import messy_head

    return messy_head(n, seed=seed, closed=closed)


def test_messy_open_head_keeps_its_neck():
    from geoface.synth import procedural_head

    V, F = _messy(8000, 3, closed=False)
    before = topology_report(V, F)
    assert not before.manifold and before.components > 1 and before.boundary_loops > 1
    res = make_disk(V, F)
    r = assert_disk(res)
    assert_idempotent(res)
    steps = {c["step"] for c in res.changes}
    assert {"merge_vertices", "split_nonmanifold_edges", "remove_components", "fill_hole"} <= steps
    head = procedural_head(n_vertices=8000, seed=3)
    assert r.boundary_loop_lengths[0] == pytest.approx(topology_report(head.V, head.F).boundary_loop_lengths[0], rel=1e-6)
    assert res.area_after == pytest.approx(face_areas(head.V, head.F).sum(), rel=0.02)


def test_messy_closed_head_is_cut_at_the_neck():
    from geoface.mesh.core import boundary_loops

    V, F = _messy(8000, 4, closed=True)
    res = make_disk(V, F, open="plane")
    assert_disk(res)
    assert_idempotent(res)
    assert "open_plane" in {c["step"] for c in res.changes}
    up = res.frame.up  # the face's: the cut is level with it, wherever the file's axes are
    loop_y = res.V[boundary_loops(res.F)[0]] @ up
    assert loop_y.max() - loop_y.min() < 1e-9  # a planar cut ...
    assert loop_y[0] < np.quantile(res.V @ up, 0.02)  # ... at the bottom (the neck)


def test_quiet_argument_overrides_the_global_switch(capsys, monkeypatch):
    from geoface import progress

    monkeypatch.setattr(progress, "QUIET", False)
    monkeypatch.setattr(progress, "VERBOSE", True)  # make_disk's steps are detail lines (-v)
    V, F = sphere(500)
    make_disk(V, F, quiet=True)
    assert capsys.readouterr().err == ""
    make_disk(V, F)
    assert "make_disk:" in capsys.readouterr().err
    monkeypatch.setattr(progress, "VERBOSE", False)
    make_disk(V, F)
    err = capsys.readouterr().err
    assert "removing handles" not in err and "cleaning" not in err  # the steps are detail
    assert "UNCERTAIN" in err  # an uncertain frame (a sphere) is said without -v


def test_a_small_hole_is_not_the_opening():
    """A closed surface with one missing triangle: keeping that hole as the disk boundary
    would squeeze the whole sphere into a point of the map (and leave 3 boundary vertices
    for 4 corners). It is filled and the surface cut open at the bottom instead; a real
    opening (a hemisphere's rim) is kept."""
    V, F = sphere(1.0, 3)
    res = make_disk(V, F[1:], up="z")
    rep = topology_report(res.V, res.F)
    assert rep.is_disk
    b = rep.boundary_loop_lengths[0]
    assert b > 1.0  # a plane cut near the bottom, not the 0.3-long triangle hole
    assert abs(face_areas(res.V, res.F).sum() - 4 * np.pi) / (4 * np.pi) < 0.05
    # an opening as large as a hemisphere's rim stays the boundary
    Vh, Fh = hemisphere(1.0, 12)
    rh = make_disk(Vh, Fh)
    assert abs(topology_report(rh.V, rh.F).boundary_loop_lengths[0] - 2 * np.pi) < 0.1
    # an 8-vertex hole 0.35 sqrt(area) long is an opening by default; min_opening=0.5 refuses it
    nb = np.unique(F[(F == 0).any(1)])
    F2 = F[~np.isin(F, nb[:3]).any(1)]
    kept = make_disk(V, F2, up="z")
    assert topology_report(kept.V, kept.F).boundary_loop_lengths[0] < 1.3
    recut = make_disk(V, F2, up="z", min_opening=0.5)
    assert topology_report(recut.V, recut.F).boundary_loop_lengths[0] > 1.3


def test_a_plane_cut_too_small_to_be_an_opening_is_raised():
    """genus2 lies flat: a cut 2% above its lowest point leaves a 3-vertex opening. The cut
    is raised until the opening is one (while keeping 90% of the area)."""
    from geoface.mesh.core import boundary_loops

    V, F = genus2(48)
    res = make_disk(V, F, up="z")
    assert_disk(res)
    loop = boundary_loops(res.F)[0]
    L = np.linalg.norm(res.V[np.roll(loop, -1)] - res.V[loop], axis=1).sum()
    assert len(loop) >= 8 and L >= 0.1 * np.sqrt(res.area_after)
    assert res.area_after >= 0.9 * res.area_before
