"""Which way a mesh faces (geoface.mesh.frame): real scans, ICT heads at any yaw, and the
off-screen picture that `geoface view` takes by default."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geoface import GeofaceError
from geoface.mesh.frame import mesh_frame, parse_up, points_frame

DATA = Path(__file__).resolve().parents[1] / "data" / "meshes"

#: the direction each test mesh faces (looked up by eye on renders from the six axes); the
#: beetle is a car (either end will do) and is left out
FACING = {
    "camelhead.off": (0, 0, 1), "decimated-max.obj": (0, 0, -1), "face.obj": (0, 0, 1),
    "female02.obj": (0, 0, 1), "lion.off": (0, 0, -1), "male02.obj": (0, 0, 1),
    "ninjaHead_Low.obj": (0, 0, 1), "spot.obj": (0, 0, -1),
}


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_parse_up():
    assert np.allclose(parse_up(None), [0, 1, 0])
    assert np.allclose(parse_up("-z"), [0, 0, -1]) and np.allclose(parse_up("+x"), [1, 0, 0])
    assert np.allclose(parse_up("0,0,2"), [0, 0, 1])
    for bad in ("w", "1,2", "0,0,0", "nan,0,1"):
        with pytest.raises(GeofaceError):
            parse_up(bad)


@pytest.mark.parametrize("name", sorted(FACING))
def test_real_meshes_face_the_camera(name):
    from geoface.mesh.io import load_mesh

    m = load_mesh(DATA / name)
    fr = mesh_frame(m.V, m.F)
    B = np.column_stack([fr.right, fr.up, fr.front])
    assert np.allclose(B.T @ B, np.eye(3), atol=1e-9) and np.linalg.det(B) > 0  # a right-handed frame
    assert _angle(fr.front, FACING[name]) < 30, (name, fr.front, fr.how)


@pytest.fixture(scope="module")
def ict():
    from geoface.synth.ict import ict_head, load_ict_model

    return ict_head(load_ict_model(), seed=5)


@pytest.mark.parametrize("yaw", [0, 90, 180, 237])
def test_ict_head_at_any_yaw(ict, yaw):
    """The model faces +Z; turned about the vertical, the frame turns with it, with or without
    the face mask; Z-up data with --up z the same."""
    R = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    truth = R @ [0.0, 0.0, 1.0]
    V = ict.V @ R.T
    shape = mesh_frame(V, ict.F)
    assert _angle(shape.front, truth) < 15 and shape.how.startswith("symmetry"), shape
    assert _angle(mesh_frame(V, ict.F, face=ict.face_mask).front, truth) < 15
    Zup = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # y -> z
    zf = mesh_frame(V @ Zup.T, ict.F, up="+z")
    assert _angle(zf.front, Zup @ truth) < 15 and np.allclose(zf.up, [0, 0, 1])
    # the splat viewer's variant: the vertices as points
    assert _angle(points_frame(V).front, truth) < 20


def test_face_region_is_validated(ict):
    with pytest.raises(GeofaceError, match="face region"):
        mesh_frame(ict.V, ict.F, face=[len(ict.V) + 3])


@pytest.mark.parametrize("facing", ["-z", "+x"])
def test_view_screenshot_shows_the_face(ict, facing, tmp_path, capfd):
    """`geoface view --screenshot` of a head scanned facing −Z or +X: the face (painted red)
    fills the picture by default, and `--view back` shows hardly any of it."""
    pytest.importorskip("pyvista")
    from geoface.cli import main
    from geoface.mesh.io import Mesh, save_mesh

    yaw = {"-z": 180, "+x": 90}[facing]
    R = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    colors = np.tile([0.6, 0.6, 0.6, 1.0], (len(ict.V), 1))
    colors[ict.face_mask] = [0.9, 0.05, 0.05, 1.0]
    path = tmp_path / "head.ply"
    save_mesh(path, Mesh(ict.V @ R.T, ict.F, colors=colors))

    def red_share(view):
        import cv2

        out = tmp_path / f"{view}.png"
        assert main(["view", str(path), "--screenshot", str(out), "--size", "160,160", "--view", view]) == 0
        img = cv2.imread(str(out))[..., ::-1].astype(int)
        drawn = (img < 245).any(-1)  # the background is white
        red = (img[..., 0] > img[..., 1] + 60) & drawn
        return red.sum() / max(drawn.sum(), 1)

    front, back = red_share("front"), red_share("back")
    assert front > 0.35 and back < 0.15 and front > 4 * back  # from behind: only the ears' rims and the neck
    if not __import__("geoface.viz").viz.has_display():  # VTK's warning about the missing X server stays hidden
        assert "X server" not in capfd.readouterr().err


def test_flat_meshes_are_seen_face_on():
    """A sheet standing upright is looked at from the side its normals face; one lying flat, from above."""
    from geoface.synth.surfaces import square_grid

    V, F = square_grid(8, 1.0)
    V = np.asarray(V, np.float64)  # in the xy plane, normals +z
    fr = mesh_frame(V, F)
    assert np.allclose(fr.front, [0, 0, 1]) and np.allclose(fr.up, [0, 1, 0])
    assert np.allclose(mesh_frame(V, F[:, ::-1]).front, [0, 0, -1])  # turned over
    lying = mesh_frame(V[:, [0, 2, 1]], F[:, ::-1])  # in the xz plane, normals +y
    assert np.allclose(lying.front, [0, 1, 0]) and abs(lying.up @ [0, 1, 0]) < 1e-9
