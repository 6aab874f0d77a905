import numpy as np
import pytest

from geoface.errors import MeshTopologyError
from geoface.mesh import topology_report
from geoface.repair import clean, remove_handles
from geoface.synth import cylinder, genus2, punch_holes, sphere, torus


def test_torus_cut_along_its_meridian():
    R, r = 1.0, 0.3
    V, F = torus(R, r, 64, 24)
    res = remove_handles(V, F)
    rep = topology_report(res.V, res.F)
    assert rep.closed and rep.genus == 0 and rep.manifold and rep.consistently_oriented
    assert len(res.changes) == 1
    # the shortest non-separating loop of this torus is a meridian: length 2*pi*r (inscribed 24-gon)
    assert res.changes[0]["loop_length"] == pytest.approx(24 * 2 * r * np.sin(np.pi / 24), rel=1e-9)
    # capping a tube of radius r adds about two disks of area pi r^2
    assert res.changes[0]["area_added"] == pytest.approx(2 * np.pi * r * r, rel=0.35)


def test_a_torus_of_more_than_46k_faces_is_cut_along_a_meridian():
    """Above 46,340 faces the dual tree's face pairs no longer fit int32 keys: the cotree came out
    wrong and every loop went round a single face (which cut off a triangle, never a handle)."""
    R, r = 1.0, 0.3
    V, F = torus(R, r, 250, 96)
    assert len(F) > 46_340
    res = remove_handles(V, F)
    rep = topology_report(res.V, res.F)
    assert rep.closed and rep.genus == 0 and rep.components == 1
    assert res.changes[0]["loop_length"] == pytest.approx(96 * 2 * r * np.sin(np.pi / 96), rel=1e-9)


def test_genus_two_needs_two_cuts():
    V, F = genus2(48)
    res = remove_handles(V, F)
    rep = topology_report(res.V, res.F)
    assert rep.genus == 0 and rep.closed and rep.components == 1
    assert [c["step"] for c in res.changes] == ["cut_handle", "cut_handle"]


def test_open_torus_keeps_its_boundary():
    V, F = torus(1.0, 0.3, 48, 24)
    Vh, Fh = punch_holes(V, F, n_holes=1, radius=0.05, seed=2)
    c = clean(Vh, Fh)
    res = remove_handles(c.V, c.F)
    rep = topology_report(res.V, res.F)
    assert rep.is_disk
    # the boundary is untouched: same loop length as before
    assert rep.boundary_loop_lengths == pytest.approx(topology_report(c.V, c.F).boundary_loop_lengths)


def test_genus_zero_is_untouched_and_bad_input_refused():
    V, F = sphere(1.0, 2)
    res = remove_handles(V, F)
    assert res.changes == [] and np.array_equal(res.F, F)
    with pytest.raises(MeshTopologyError, match="boundary loop"):
        remove_handles(*cylinder())
    with pytest.raises(MeshTopologyError, match="max_handles"):
        remove_handles(*genus2(40), max_handles=1)
