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
