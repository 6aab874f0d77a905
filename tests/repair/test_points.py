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
    """Clouds that have no surface get one line naming why: the wrong shape, a handful of points,
    points on a line (1,000 collinear points once made a 1,562-vertex surface) or in a plane, an
    infinite coordinate, NaN normals."""
    rng = np.random.default_rng(0)
    t = rng.random(1000)
    blob = rng.normal(size=(200, 3))
    for P, N, why in ((np.zeros((30, 2)), None, r"\(n, 3\)"), (rng.random((5, 3)), None, "at least 20"),
                      (np.column_stack([t, 2 * t, -t]), None, "on a line"),
                      (np.column_stack([t, rng.random(1000), np.zeros(1000)]), None, "in a plane"),
                      (np.vstack([blob, [[np.inf, 0, 0]]]), None, "not finite"),
                      (blob, np.where(np.arange(200)[:, None] < 3, np.nan, blob), "normals are not finite")):
        with pytest.raises(GeofaceError, match=why):
            surface_from_points(P, N)


def _write_cloud(path: Path, P, N=None):
    """``P`` (and normals ``N``) as the file ``path`` names: PLY (ascii or binary by the stem's
    end), OBJ (``v``/``vn``), OFF (no faces), XYZ (3 or 6 columns)."""
    fmt = path.suffix.lower()
    if fmt == ".ply":
        binary = path.stem.endswith("bin")
        props = ["x", "y", "z"] + (["nx", "ny", "nz"] if N is not None else [])
        head = ("ply\nformat " + ("binary_little_endian" if binary else "ascii") + f" 1.0\nelement vertex {len(P)}\n"
                + "".join(f"property float {p}\n" for p in props) + "end_header\n")
        A = P if N is None else np.hstack([P, N])
        with path.open("wb") as f:
            f.write(head.encode())
            if binary:
                f.write(A.astype("<f4").tobytes())
            else:
                f.write("".join(" ".join(f"{x:.6f}" for x in row) + "\n" for row in A.astype(np.float32)).encode())
    elif fmt == ".obj":
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in P.astype(np.float32)]
        lines += [] if N is None else [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in N.astype(np.float32)]
        path.write_text("\n".join(lines) + "\n")
    elif fmt == ".off":
        A = P if N is None else np.hstack([P, N])
        path.write_text(("NOFF" if N is not None else "OFF") + f"\n{len(P)} 0 0\n"
                        + "".join(" ".join(f"{x:.6f}" for x in row) + "\n" for row in A.astype(np.float32)))
    else:
        A = P if N is None else np.hstack([P, N])
        np.savetxt(path, A.astype(np.float32), fmt="%.6f")


def test_every_cloud_format_reads_the_same_points_and_normals(tmp_path):
    """The vertices and normals of a real scan (face.obj, decimated) as ASCII and binary PLY, OBJ
    (``vn`` in step with ``v``), NOFF and XYZ, and without normals: the same points from every file (to float32), the same normals where the format
    has them, hence the same surface (to rounding; made from two of them) (an ASCII PLY once crashed:
    its columns are a dict, not a structured array)."""
    import trimesh

    from tests.helpers import shared_mesh

    m = load_mesh(shared_mesh("face.obj"))
    t = trimesh.Trimesh(m.V, m.F, process=False)
    P, N = np.asarray(t.vertices[::20], np.float64), np.asarray(t.vertex_normals[::20], np.float64)
    ref = P.astype(np.float32).astype(np.float64)
    surfaces = {}
    for name, with_normals in (("a.ply", True), ("abin.ply", True), ("a.xyz", True), ("a.obj", True), ("a.off", True),
                               ("b.obj", False), ("b.off", False), ("b.xyz", False)):
        f = tmp_path / name
        _write_cloud(f, P, N if with_normals else None)
        Q, M = load_points(f)
        np.testing.assert_allclose(Q, ref, atol=2e-5 * np.abs(ref).max(), err_msg=name)
        assert (M is not None) == with_normals, name
        if with_normals:
            np.testing.assert_allclose(M, N, atol=1e-5, err_msg=name)
        if name in ("a.ply", "a.off"):  # the rest agree with these to float32 rounding
            s = surface_from_points(Q, M, depth=6)
            surfaces[name] = (len(s.V), float(topology_report(s.V, s.F).surface_area))
    counts, areas = {v[0] for v in surfaces.values()}, [v[1] for v in surfaces.values()]
    assert len(counts) == 1 and max(areas) - min(areas) < 1e-5 * max(areas), surfaces  # float32 text vs binary


def test_an_off_point_cloud_is_a_point_cloud(tmp_path):
    """An OFF with vertices and no faces reads as a point cloud (the CLI reconstructs a surface),
    not as a broken mesh."""
    from geoface.errors import PointCloudError

    f = tmp_path / "c.off"
    _write_cloud(f, np.random.default_rng(0).normal(size=(40, 3)))
    with pytest.raises(PointCloudError, match="point cloud"):
        load_mesh(f)
