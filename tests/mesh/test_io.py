import warnings

import numpy as np
import pytest

from geoface.errors import GeofaceWarning, InvalidMeshError, MeshFormatError
from geoface.mesh import topology_report
from geoface.mesh.io import Mesh, load_mesh, save_mesh
from geoface.synth import cylinder, square_grid
from tests.helpers import shared_mesh


@pytest.fixture
def grid_attrs():
    V, F = square_grid(5)
    V = V + np.array([0.123456789, -2.0, 0.5])
    rng = np.random.default_rng(0)
    return V, F, rng.random((len(V), 3)), V[:, :2] - V[:, :2].min(0), (rng.random((8, 8, 3)) * 255).astype(np.uint8)


@pytest.mark.parametrize("ext, tol", [("obj", 1e-7), ("ply", 1e-6), ("off", 1e-9), ("stl", 1e-6), ("glb", 1e-6)])
def test_geometry_round_trip(tmp_path, grid_attrs, ext, tol):
    V, F, *_ = grid_attrs
    p = tmp_path / f"m.{ext}"
    save_mesh(p, V=V, F=F)
    m = load_mesh(p)
    assert len(m.V) == len(V) and len(m.F) == len(F)  # STL soups are welded back
    assert np.abs(m.V[m.F] - V[F]).max() < tol
    assert topology_report(m.V, m.F).is_disk


@pytest.mark.parametrize("ext", ["obj", "ply", "glb"])
def test_vertex_colours_survive(tmp_path, grid_attrs, ext):
    V, F, C, *_ = grid_attrs
    save_mesh(tmp_path / f"c.{ext}", Mesh(V, F, colors=C))
    m = load_mesh(tmp_path / f"c.{ext}")
    assert m.colors is not None
    assert np.abs(m.colors[:, :3][m.F] - C[F]).max() <= 0.5 / 255 + 1e-9  # 8-bit quantisation


@pytest.mark.parametrize("ext, texture", [("obj", True), ("glb", True), ("ply", False)])
def test_uvs_and_texture_survive(tmp_path, grid_attrs, ext, texture):
    V, F, _, UV, T = grid_attrs
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        save_mesh(tmp_path / f"u.{ext}", Mesh.from_vertex_uv(V, F, UV, texture=T))
    m = load_mesh(tmp_path / f"u.{ext}")
    assert np.abs(m.UV[m.FUV] - UV[F]).max() < 1e-6
    if texture:
        assert np.array_equal(m.texture[..., :3], T)
        assert not rec
    else:  # PLY cannot hold the image: said out loud
        assert any(issubclass(w.category, GeofaceWarning) and "texture" in str(w.message) for w in rec)


@pytest.mark.parametrize("ext", ["stl", "off"])
def test_dropping_attributes_warns(tmp_path, grid_attrs, ext):
    V, F, C, UV, _ = grid_attrs
    with pytest.warns(GeofaceWarning, match="cannot store"):
        save_mesh(tmp_path / f"w.{ext}", Mesh(V, F, colors=C))
    with pytest.warns(GeofaceWarning, match="UVs"):
        save_mesh(tmp_path / f"w2.{ext}", Mesh.from_vertex_uv(V, F, UV))


def test_uv_seams_are_kept_while_geometry_is_welded(tmp_path):
    # a tube with a UV seam: the file splits seam vertices, geoface welds them back
    V, F = cylinder(1.0, 1.0, 12, 4)
    n_around, n_high = 12, 4
    i = np.arange(len(V)) // n_high
    j = np.arange(len(V)) % n_high
    UV = np.stack([i / n_around, j / (n_high - 1)], 1)
    FUV = F.copy()
    # faces crossing the seam use a second copy of column 0 at u = 1
    seam_faces = (i[F] == n_around - 1).any(1) & (i[F] == 0).any(1)
    extra = np.stack([np.ones(n_high), np.arange(n_high) / (n_high - 1)], 1)
    UV2 = np.vstack([UV, extra])
    cols = FUV[seam_faces]
    FUV[seam_faces] = np.where(i[cols] == 0, len(UV) + j[cols], cols)
    save_mesh(tmp_path / "tube.obj", Mesh(V, F, UV=UV2, FUV=FUV))
    m = load_mesh(tmp_path / "tube.obj")
    assert len(m.V) == len(V)  # welded: the seam is not a boundary
    assert topology_report(m.V, m.F).boundary_loops == 2
    assert len(np.unique(m.UV[m.FUV].reshape(-1, 2), axis=0)) == len(UV2)
    assert np.abs(m.UV[m.FUV] - UV2[FUV]).max() < 1e-7


def test_real_meshes_keep_uvs():
    m = load_mesh(shared_mesh("spot.obj"))
    assert m.UV is not None and len(m.UV) > len(m.V)  # seams: more UVs than vertices
    r = topology_report(m.V, m.F)
    assert r.closed and r.genus == 0
    m = load_mesh(shared_mesh("ninjaHead_Low.obj"))
    assert m.UV is not None and topology_report(m.V, m.F).is_disk


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "empty"),
        (b"hello, I am not a mesh\n", "no triangle"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "point cloud"),
        (b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "cannot read|indexes"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: face index 0"),
    ],
)
def test_bad_obj_files(tmp_path, content, match):
    p = tmp_path / "bad.obj"
    p.write_bytes(content)
    with pytest.raises((MeshFormatError, InvalidMeshError), match=match):
        load_mesh(p)


def test_bad_paths_and_binary_garbage(tmp_path):
    with pytest.raises(MeshFormatError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(MeshFormatError, match="unsupported mesh format"):
        load_mesh(tmp_path / "x.xyz")
    p = tmp_path / "garbage.ply"
    p.write_bytes(np.random.default_rng(1).bytes(500))
    with pytest.raises(MeshFormatError):
        load_mesh(p)
    p = tmp_path / "garbage.glb"
    p.write_bytes(b"glTF" + np.random.default_rng(2).bytes(200))
    with pytest.raises(MeshFormatError):
        load_mesh(p)


def test_write_is_atomic(tmp_path, grid_attrs, monkeypatch):
    V, F, *_ = grid_attrs
    out = tmp_path / "out.ply"
    out.write_bytes(b"previous contents")
    import trimesh

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(trimesh.exchange.export, "export_mesh", boom)
    with pytest.raises(RuntimeError):
        save_mesh(out, V=V, F=F)
    assert out.read_bytes() == b"previous contents"
    assert [p.name for p in tmp_path.iterdir()] == ["out.ply"]  # no temp file left behind


def test_mesh_validates_attributes():
    V, F = square_grid(3)
    with pytest.raises(InvalidMeshError, match="colors"):
        Mesh(V, F, colors=np.zeros((2, 3)))
    with pytest.raises(InvalidMeshError, match="together"):
        Mesh(V, F, UV=np.zeros((9, 2)))
    with pytest.raises(InvalidMeshError, match="FUV"):
        Mesh(V, F, UV=np.zeros((9, 2)), FUV=F + 100)


@pytest.mark.parametrize("ext", ["obj", "ply", "glb", "off"])
def test_vertex_order_is_preserved(tmp_path, ext):
    # landmark and mask indices refer to vertex order: it must survive a round trip
    from geoface.synth import disk_grid

    V, F = disk_grid(6)
    perm = np.random.default_rng(0).permutation(len(V))
    V, F = V[perm], np.argsort(perm)[F]
    mesh = Mesh.from_vertex_uv(V, F, V[:, :2] * 0.5 + 0.5) if ext != "off" else Mesh(V, F)
    save_mesh(tmp_path / f"o.{ext}", mesh)
    m = load_mesh(tmp_path / f"o.{ext}")
    assert np.allclose(m.V, V, atol=1e-6) and np.array_equal(m.F, F)


def test_uvs_without_an_image_write_no_placeholder_texture(tmp_path):
    """An OBJ with UVs and no texture gets no invented image (trimesh's 2x2 grey) and an MTL
    without map_Kd; the UVs read back."""
    from geoface.synth import square_grid

    V, F = square_grid(5)
    UV = V[:, :2].copy()
    save_mesh(tmp_path / "g.obj", V=V, F=F, UV=UV)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.mtl", "g.obj"]
    assert "map_" not in (tmp_path / "g.mtl").read_text()
    m = load_mesh(tmp_path / "g.obj")
    assert m.texture is None and m.UV is not None and len(m.UV) == len(UV)


def test_obj_numbers_are_written_as_printf_would():
    """The array formatter of OBJ text matches ``%.*f`` (away from exact ties), drops the sign of
    a negative number that rounds to zero, and writes 1-based ``a/a`` faces with UVs."""
    from geoface.mesh import objtext

    rng = np.random.default_rng(3)
    for scale, d in [(1.0, 8), (1e3, 8), (1e-6, 15)]:
        x = rng.standard_normal(5000) * scale
        x[0] = -0.1 * 10.0**-d
        ours = objtext._lines("v ", [objtext.fixed_columns(x, d)]).decode().splitlines()
        ref = [f"v {v:.{d}f}".replace("v -0." + "0" * d, "v 0." + "0" * d) for v in x]
        assert ours == ref
    V = rng.random((4, 3))
    body = objtext.obj_body(V, np.array([[0, 1, 2], [0, 2, 3]]), rng.random((4, 2)), 8).decode().splitlines()
    assert body[-2:] == ["f 1/1 2/2 3/3", "f 1/1 3/3 4/4"] and len(body) == 10


def test_obj_with_uv_seams_and_texture_round_trips(tmp_path):
    """A textured mesh with a UV seam: the OBJ splits the seam's vertices, keeps the texture, and
    reads back with the same positions per corner and the same UVs."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.5]], float) * 1e3
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]])
    FUV = np.array([[0, 1, 2], [4, 2, 3]])  # vertex 0 has two UVs: a seam
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[..., 0] = 200
    save_mesh(tmp_path / "m.obj", Mesh(V, F, UV=UV, FUV=FUV, texture=tex))
    lines = (tmp_path / "m.obj").read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == 5 and sum(ln.startswith("vt ") for ln in lines) == 5
    back = load_mesh(tmp_path / "m.obj")
    np.testing.assert_allclose(back.V[back.F], V[F], atol=1e-6)
    np.testing.assert_allclose(back.UV[back.FUV], UV[FUV], atol=1e-8)
    assert back.texture is not None and back.texture[0, 0, 0] == 200
    assert (tmp_path / "m.mtl").read_text().count("map_Kd m_texture.png") == 1


def _fast_path_matches_trimesh(path, monkeypatch):
    """The NumPy reader takes ``path``, and reads what trimesh reads from it."""
    from geoface.mesh import io

    assert io._plain_obj(path.read_text()) is not None
    fast = load_mesh(path)
    with monkeypatch.context() as mp:
        mp.setattr(io, "_plain_obj", lambda text: None)
        slow = load_mesh(path)
    np.testing.assert_array_equal(fast.V, slow.V)
    np.testing.assert_array_equal(fast.F, slow.F)


@pytest.mark.parametrize("text", [
    "# a comment\no head\nv 0 0 0\nv 1 0 0\n\nv 0 1 0\ng part\ns off\nv 0 0 1\nf 1 2 3\nf 1 3 4\n",
    "v 0 0 0\r\nv 1e-3 0 0\r\nv 0 1 0\r\nv 9 9 9\r\nv 0 0 1\r\nf 1 2 3\r\nf 1 3 5\r\n",  # CRLF, unused vertex
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 0\nv 0 0 1\nf 1 2 3\nf 4 3 5\n",  # a duplicate to weld
])
def test_plain_obj_fast_path_reads_what_trimesh_reads(tmp_path, monkeypatch, text):
    p = tmp_path / "m.obj"
    p.write_text(text, newline="")
    _fast_path_matches_trimesh(p, monkeypatch)


def test_plain_obj_fast_path_on_a_real_scan_and_what_it_leaves_to_trimesh(monkeypatch):
    from geoface.mesh import io

    _fast_path_matches_trimesh(shared_mesh("face.obj"), monkeypatch)
    # normals, UVs, quads, relative indices, colours: trimesh's reader
    for text in ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
                 "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n", "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0 1 0 0\nf 1 2 3\n",
                 "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"):
        assert io._plain_obj(text) is None


def test_a_negative_obj_index_before_the_first_vertex_is_refused(tmp_path):
    """``f -5 -6 -7`` after three vertices points before the file's first vertex: refused with the
    line, not wrapped round to the end (it once read as one face); ``f -3 -2 -1`` is the triangle."""
    from geoface.errors import MeshFormatError
    from geoface.mesh.io import load_mesh

    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -5 -6 -7\n")
    with pytest.raises(MeshFormatError, match=r"line 4: index -5 points before the first vertex"):
        load_mesh(tmp_path / "bad.obj")
    (tmp_path / "ok.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\n")
    m = load_mesh(tmp_path / "ok.obj")
    assert m.F.tolist() == [[0, 1, 2]] and len(m.V) == 3
