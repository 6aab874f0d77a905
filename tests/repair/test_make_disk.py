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
    # provenance: a vertex mapped to an original that was not split sits exactly where it
    # was; copies of a split vertex moved only by the small separation
    ok = res.vertex_map >= 0
    d = np.linalg.norm(res.V[ok] - m.V[res.vertex_map[ok]], axis=1)
    from geoface.mesh.core import nonmanifold_vertices

    split = np.isin(res.vertex_map[ok], nonmanifold_vertices(m.F, len(m.V)))
    assert d[~split].max() == 0.0
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
