"""One check per mesh per ``convert``: the user's mesh is validated at the entry, every step
below works on meshes derived from it (``geoface.mesh.core.checked_meshes``), and each set of
faces gets its edge topology built once; bad input still gets its one-line error."""
from __future__ import annotations

import numpy as np
import pytest

import geoface.mesh.core as core
from geoface.errors import InvalidMeshError
from geoface.mesh.mesh_data import Mesh
from geoface.pipeline import ConvertOptions, convert


@pytest.fixture
def counted(monkeypatch):
    """Every topology build's faces, by content."""
    built = []
    real = core._edge_topology

    def spy(F):
        built.append(np.ascontiguousarray(F).tobytes())
        return real(F)

    monkeypatch.setattr(core, "_edge_topology", spy)
    return built


def test_one_check_and_one_topology_per_mesh_in_a_convert(tmp_path, counted):
    from geoface.synth.ict import ict_head

    h = ict_head(seed=0)
    mesh = Mesh(h.V, h.F)
    before = core.CHECKS.validations
    convert(mesh, tmp_path / "out", ConvertOptions(res=32, augment=2), quiet=True)
    assert core.CHECKS.validations - before == 1
    assert counted and len(counted) == len(set(counted)), "a set of faces had its topology built twice"


def test_outside_a_convert_every_call_checks():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    before = core.CHECKS.validations
    core.check_mesh(V, F)
    core.check_mesh(V, F)
    assert core.CHECKS.validations - before == 2
    with core.checked_meshes():
        a = core.edge_topology(F)
        assert core.edge_topology(F.copy()) is a  # the same faces: built once
        with pytest.raises(ValueError):
            a.E[0, 0] = 5  # shared, so read-only
    assert core.edge_topology(F) is not a


@pytest.mark.parametrize("where, value, match", [("V", np.nan, "NaN"), ("F", 3, "indexes vertices")])
def test_bad_input_is_still_refused_at_the_entry(tmp_path, where, value, match):
    """A Mesh changed in place after it was made is checked again at convert's entry."""
    mesh = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))
    getattr(mesh, where)[0, 2] = value
    with pytest.raises(InvalidMeshError, match=match):
        convert(mesh, tmp_path / "out", ConvertOptions(res=32), quiet=True)


@pytest.mark.parametrize("residual, ok", [(4.5e-9, True), (1e-3, False)])
def test_a_flow_stalled_at_the_floating_point_floor_is_kept(tmp_path, monkeypatch, residual, ok):
    """A scan whose Ricci flow stops at 4.5e-9 rad, short of the solver's 1e-9 (seen on an ICT
    head's Poisson surface), still converts; one that stops far off does not."""
    import dataclasses

    from geoface.errors import GeofaceError
    from geoface.param.ricci import RicciFlowSolver
    from geoface.synth.ict import ict_head

    real = RicciFlowSolver.solve

    def stalled(self, *a, **k):
        r = real(self, *a, **k)
        return dataclasses.replace(r, converged=False, residual=residual)

    monkeypatch.setattr(RicciFlowSolver, "solve", stalled)
    h = ict_head(seed=0)
    opts = ConvertOptions(res=32, find_face=False, method="conformal")
    if ok:
        m = convert(Mesh(h.V, h.F), tmp_path / "o", opts, quiet=True)
        assert m["sets"][0]["ricci"]["converged"] is False
    else:
        with pytest.raises(GeofaceError, match="did not converge"):
            convert(Mesh(h.V, h.F), tmp_path / "o", opts, quiet=True)
