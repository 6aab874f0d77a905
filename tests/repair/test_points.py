"""Point clouds become surfaces (screened Poisson through pymeshlab) that the pipeline converts:
an open face scan stays open (Poisson's closure trimmed away), a closed bust stays closed, with
or without normals in the file."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from geoface import GeofaceError
from geoface.mesh.io import load_mesh
from geoface.mesh.topology import topology_report
from geoface.pipeline import reconstruction_error
from geoface.repair.points import load_points, surface_from_points

MESHES = Path(__file__).resolve().parents[1] / "data" / "meshes"


def _sample(name, n, seed=0):
    import trimesh

    m = load_mesh(MESHES / name)
    tm = trimesh.Trimesh(m.V, m.F, process=False)
    P, fi = trimesh.sample.sample_surface_even(tm, n, seed=seed)
    return m, np.asarray(P), np.asarray(tm.face_normals[fi])


def test_an_open_face_scan_stays_open_and_close():
    """Without normals (estimated); the file's normals are used by the .xyz test below."""
    m, P, _ = _sample("face.obj", 8000)
    s = surface_from_points(P)
    rep = topology_report(s.V, s.F)
    assert rep.components == 1 and rep.boundary_loops == 1 and rep.genus == 0, rep.format()
    err = reconstruction_error(m.V, m.F, s.V, s.F)
    # both ways: no cap over the open back (rec -> scan; a cap would be ~30% of the diagonal; the
    # surface may reach 3 point spacings past the scan's edge) and nothing of the face lost
    assert err["rec_to_ref_max"] < 0.04 and err["ref_to_rec_max"] < 0.015 and err["mean"] < 0.002, err
    assert s.normals_estimated


def test_a_closed_bust_stays_closed():
    m, P, _ = _sample("decimated-max.obj", 8000)
    s = surface_from_points(P)
    rep = topology_report(s.V, s.F)
    assert rep.components == 1 and rep.boundary_loops == 0 and rep.genus == 0, rep.format()
    assert reconstruction_error(m.V, m.F, s.V, s.F)["mean"] < 0.002


def test_convert_and_repair_take_a_point_cloud(tmp_path, capsys):
    import trimesh

    from geoface.cli import main

    _, P, N = _sample("face.obj", 4000)
    trimesh.PointCloud(P).export(tmp_path / "cloud.ply")
    np.savetxt(tmp_path / "cloud.xyz", np.hstack([P, N]), fmt="%.6f")
    assert load_points(tmp_path / "cloud.xyz")[1] is not None
    assert main(["convert", str(tmp_path / "cloud.ply"), "-o", str(tmp_path / "g"), "--res", "32"]) == 0
    assert "0 flipped" in capsys.readouterr().out and (tmp_path / "g" / "position.png").is_file()
    assert main(["repair", str(tmp_path / "cloud.xyz"), "-o", str(tmp_path / "d.obj"), "-q"]) == 0
    assert topology_report(*(lambda x: (x.V, x.F))(load_mesh(tmp_path / "d.obj"))).is_disk
    (tmp_path / "few.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    assert main(["convert", str(tmp_path / "few.xyz"), "-o", str(tmp_path / "h"), "-q"]) == 2
    assert "at least 20 distinct points" in capsys.readouterr().err


def test_bad_points():
    with pytest.raises(GeofaceError, match=r"\(n, 3\)"):
        surface_from_points(np.zeros((30, 2)))
