import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.camera import Camera, look_at, orbit


def test_look_at_centres_target_and_up_is_image_up():
    cam = look_at([1.0, 2.0, 5.0], [0.2, 0.1, -0.3], up=[0, 1, 0], width=64, height=48)
    uv, z = cam.project(np.array([[0.2, 0.1, -0.3]]))
    np.testing.assert_allclose(uv[0], [32, 24], atol=1e-9)
    assert z[0] == pytest.approx(np.linalg.norm([0.8, 1.9, 5.3]))
    np.testing.assert_allclose(cam.center, [1, 2, 5], atol=1e-12)
    # a point above the target appears higher in the image (smaller v)
    uv2, _ = cam.project(np.array([[0.2, 0.6, -0.3]]))
    assert uv2[0, 1] < 24
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cam.R) == pytest.approx(1.0)


def test_look_at_right_is_image_right():
    cam = look_at([0, 0, 3], [0, 0, 0])
    uv, _ = cam.project(np.array([[0.5, 0, 0]]))  # camera on +z looking at -z: world +x is right
    assert uv[0, 0] > 128


def test_orbit_distance_elevation_and_targets():
    cams = orbit(8, 2.5, elevation=20.0, target=(0.1, 0.0, 0.2), width=32, height=32)
    assert len(cams) == 8
    for c in cams:
        d = c.center - np.array([0.1, 0.0, 0.2])
        assert np.linalg.norm(d) == pytest.approx(2.5)
        assert np.degrees(np.arcsin(d[1] / 2.5)) == pytest.approx(20.0)
        uv, z = c.project(np.array([[0.1, 0.0, 0.2]]))
        np.testing.assert_allclose(uv[0], [16, 16], atol=1e-9)
    az = [np.arctan2(c.center[0] - 0.1, c.center[2] - 0.2) for c in cams]
    np.testing.assert_allclose(np.diff(np.unwrap(az)), 2 * np.pi / 8, atol=1e-12)


def test_project_torch_matches_numpy():
    torch = pytest.importorskip("torch")
    cam = look_at([0.3, 0.2, 2.0], [0, 0, 0])
    X = np.random.default_rng(0).normal(size=(5, 3)) * 0.3
    uv, z = cam.project(X)
    uvt, zt = cam.project(torch.tensor(X))
    np.testing.assert_allclose(uvt.numpy(), uv, atol=1e-12)
    np.testing.assert_allclose(zt.numpy(), z, atol=1e-12)


def test_bad_cameras_raise():
    with pytest.raises(GeofaceError, match="eye and target"):
        look_at([0, 0, 0], [0, 0, 0])
    with pytest.raises(GeofaceError, match="parallel"):
        look_at([0, 1, 0], [0, 0, 0], up=[0, 1, 0])
    with pytest.raises(GeofaceError, match="rotation"):
        Camera(10, 10, 5, 5, 10, 10, np.diag([1, 1, -1.0]), np.zeros(3))
    with pytest.raises(GeofaceError, match="n must be"):
        orbit(0, 1.0)


def test_one_camera_class_for_the_library():
    """uvmap's projection, the renderers and the avatars share one pinhole camera: the class
    from K (uvmap's OpenCV form) projects as the one from focal lengths does."""
    import geoface.nn
    import geoface.splat
    import geoface.uvmap
    from geoface.camera import Camera, look_at

    assert geoface.uvmap.Camera is Camera and geoface.nn.Camera is Camera and geoface.splat.Camera is Camera
    cam = look_at([0.3, 0.1, 2.0], [0, 0, 0], width=320, height=240, fov_y_deg=50)
    again = Camera.from_K(cam.K, cam.R, cam.t)
    assert (again.width, again.height) == (320, 240)
    X = np.random.default_rng(0).normal(size=(20, 3)) * 0.3
    assert np.allclose(again.project(X)[0], cam.project(X)[0]) and np.allclose(again.K, cam.K)


def test_rotations_agree_with_each_other_and_scipy():
    """geoface.rotations: Rodrigues and its inverse, yaw/pitch/roll, quaternions (w first) and
    look-at agree with scipy's Rotation and with each other on random rotations."""
    from scipy.spatial.transform import Rotation

    from geoface.rotations import euler_rotation, look_at_rotation, rodrigues, rotation_vector, rotmat_to_quat

    rng = np.random.default_rng(3)
    for w in rng.normal(size=(20, 3)) * 1.2:
        R = rodrigues(w)
        assert np.allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
        assert np.allclose(rodrigues(rotation_vector(R)), R, atol=1e-10)
        q = rotmat_to_quat(R[None])[0]
        assert q[0] >= 0 and np.allclose(np.abs(q), np.abs(Rotation.from_matrix(R).as_quat()[[3, 0, 1, 2]]), atol=1e-10)
    yaw, pitch, roll = 0.4, -0.2, 0.1
    assert np.allclose(euler_rotation(yaw, pitch, roll), Rotation.from_euler("YXZ", [yaw, pitch, roll]).as_matrix())
    R = look_at_rotation([0, 0, 3.0], [0, 0, 0])
    assert np.allclose(R @ [0, 0, -1.0], [0, 0, 1.0]) and np.allclose(R @ [0, 1.0, 0], [0, -1.0, 0])  # forward +z, up is -y
