import numpy as np
import pytest

from geoface.errors import InvalidMeshError
from geoface.mesh import topology_report
from geoface.mesh.core import boundary_loops, face_areas
from geoface.repair import open_at_plane, open_with_cap
from geoface.synth import sphere


def test_plane_cut_leaves_a_planar_circle():
    V, F = sphere(1.0, 4)
    res = open_at_plane(V, F, up="z", height=0.1)  # plane z = -0.8
    r = topology_report(res.V, res.F)
    assert r.boundary_loops == 1 and r.manifold
    loop = boundary_loops(res.F)[0]
    assert np.abs(res.V[loop, 2] + 0.8).max() < 1e-12
    # the rim is (close to) the circle of radius 0.6 at that height
    assert r.boundary_loop_lengths[0] == pytest.approx(2 * np.pi * 0.6, rel=0.01)
    # area of the removed cap of height 0.2 on the unit sphere: 2 pi R h
    removed = face_areas(V, F).sum() - r.surface_area
    assert removed == pytest.approx(2 * np.pi * 0.2, rel=0.02)
    assert res.changes[0]["area_removed"] == pytest.approx(removed)


def test_plane_origin_and_axis_names():
    V, F = sphere(1.0, 3)
    res = open_at_plane(V, F, up="-x", origin=(0.5, 0, 0))  # keep x < 0.5
    assert res.V[:, 0].max() <= 0.5 + 1e-12
    with pytest.raises(InvalidMeshError, match="up"):
        open_at_plane(V, F, up="w")
    with pytest.raises(InvalidMeshError, match="height"):
        open_at_plane(V, F, height=1.5)


def test_geodesic_cap_area_fraction():
    V, F = sphere(1.0, 4)
    res = open_with_cap(V, F, up="z", area_fraction=0.05)
    r = topology_report(res.V, res.F)
    assert r.boundary_loops == 1 and r.is_disk
    frac = 1 - r.surface_area / face_areas(V, F).sum()
    assert 0.05 <= frac < 0.06  # at least the requested area, one ring of faces more at most
    # centred at the lowest vertex
    assert res.changes[0]["center"] == int(np.argmin(V[:, 2]))
