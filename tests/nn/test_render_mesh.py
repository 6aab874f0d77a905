import numpy as np
import pytest

from geoface.camera import Camera, look_at
from geoface.nn.errors import RenderError
from geoface.nn.mesh_render import rasterize_mesh, render_mesh


def _axis_camera(W=40, H=30, f=20.0):
    """Camera at the origin looking down +z (R = I): pixel u = f x / z + W/2."""
    return Camera(f, f, W / 2, H / 2, W, H, np.eye(3), np.zeros(3))


def _pixel_centres(cam):
    jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    return jj, ii


def test_single_triangle_covers_the_analytic_pixel_set():
    cam = _axis_camera()
    d, f = 2.0, 20.0
    # a right triangle in the plane z = d: on screen (u, v) = (3.3, 2.7), (31.1, 2.7), (3.3, 24.2)
    uvs = np.array([[3.3, 2.7], [31.1, 2.7], [3.3, 24.2]])
    V = np.column_stack([(uvs[:, 0] - 20) * d / f, (uvs[:, 1] - 15) * d / f, np.full(3, d)])
    face, bary, depth = rasterize_mesh(V, [[0, 1, 2]], cam)
    u, v = _pixel_centres(cam)
    # inside: u >= 3.3, v >= 2.7 and below the hypotenuse from (31.1, 2.7) to (3.3, 24.2)
    hyp = (u - 3.3) / (31.1 - 3.3) + (v - 2.7) / (24.2 - 2.7) <= 1
    expected = (u >= 3.3) & (v >= 2.7) & hyp
    np.testing.assert_array_equal(face >= 0, expected)
    assert expected.sum() > 100
    np.testing.assert_allclose(bary[expected].sum(1), 1.0, atol=1e-12)


def test_flat_coloured_quad_and_background():
    V = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    c = np.array([0.2, 0.6, 0.9])
    r = render_mesh(V, F, look_at([0, 0.3, 4], [0, 0, 0], width=48, height=40),
                    np.tile(c, (4, 1)), background=(1.0, 0.0, 0.5))
    hit = r.alpha > 0
    assert 0.1 < hit.mean() < 0.9
    np.testing.assert_allclose(r.rgb[hit], np.broadcast_to(c, (hit.sum(), 3)), atol=1e-12)
    np.testing.assert_allclose(r.rgb[~hit], np.broadcast_to([1.0, 0.0, 0.5], ((~hit).sum(), 3)))
    assert set(np.unique(r.alpha)) == {0.0, 1.0}


def test_depth_of_a_plane_is_its_distance():
    cam = _axis_camera()
    for d in (0.5, 3.0, 17.0):
        V = np.array([[-50.0, -50, d], [50, -50, d], [50, 50, d], [-50, 50, d]])
        r = render_mesh(V, [[0, 1, 2], [0, 2, 3]], cam, np.ones((4, 3)))
        assert (r.alpha == 1).all()
        np.testing.assert_allclose(r.depth, d, rtol=1e-12)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_nearer_triangle_wins(order):
    cam = _axis_camera()
    near = [[-1.0, -1, 2], [1, -1, 2], [0, 1, 2]]
    far = [[-6.0, -6, 5], [6, -6, 5], [0, 6, 5]]
    V = np.array(near + far)
    F = np.array([[0, 1, 2], [3, 4, 5]])[list(order)]
    C = np.array([[1.0, 0, 0]] * 3 + [[0, 0, 1.0]] * 3)
    r = render_mesh(V, F, cam, C)
    centre = r.rgb[15, 20]
    np.testing.assert_allclose(centre, [1, 0, 0])
    assert r.depth[15, 20] == pytest.approx(2.0)
    assert (r.rgb[..., 2] == 1).any()  # the far triangle shows around the near one


def test_perspective_correct_interpolation_on_a_slanted_quad():
    cam = _axis_camera(64, 64, 40.0)
    # a quad slanted in depth: z from 1.5 (bottom) to 6 (top)
    V = np.array([[-2.0, -1.2, 1.5], [2, -1.2, 1.5], [3, 3, 6], [-3, 3, 6]])
    V[:, 1] *= -1  # image +y is down: put the near edge at the bottom of the picture
    F = np.array([[0, 1, 2], [0, 2, 3]])
    # colour channel 0 is an affine function of the world point → exact under perspective
    g = lambda P: (P[..., 2] - 1.5) / 4.5  # noqa: E731
    C = np.column_stack([g(V), np.zeros(4), np.zeros(4)])
    r = render_mesh(V, F, cam, C)
    hit = r.alpha > 0
    assert hit.sum() > 300
    u, v = _pixel_centres(cam)
    # the ray through pixel (u, v) meets the plane of the quad at depth z
    n = np.cross(V[1] - V[0], V[2] - V[0])
    dirs = np.stack([(u - 32) / 40.0, (v - 32) / 40.0, np.ones_like(u)], -1)
    z = (n @ V[0]) / (dirs @ n)
    np.testing.assert_allclose(r.depth[hit], z[hit], rtol=1e-10)
    np.testing.assert_allclose(r.rgb[hit][:, 0], g(dirs * z[..., None])[hit], atol=1e-10)
    # screen-affine (non-perspective) interpolation would be visibly off: the ray's depth is
    # not affine in (u, v) across the quad
    assert np.ptp(np.diff(z[hit.any(1)][:, 32])) > 1e-3


def test_texture_supersampling_and_headlight():
    V = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :4] = 255  # left half white (u < 0.5), right half black
    cam = look_at([0, 0, 4], [0, 0, 0], width=40, height=40)
    r = render_mesh(V, F, cam, uv=UV, texture=tex)
    assert r.rgb[20, 12].tolist() == [1.0, 1.0, 1.0] and r.rgb[20, 28].tolist() == [0.0, 0.0, 0.0]
    r4 = render_mesh(V, F, cam, np.ones((4, 3)), supersample=4)
    frac = r4.alpha[(r4.alpha > 0) & (r4.alpha < 1)]
    assert len(frac) > 0  # fractional coverage on the edges
    assert r4.alpha.sum() == pytest.approx(render_mesh(V, F, _scale_cam(cam, 4), np.ones((4, 3))).alpha.sum() / 16)
    lit = render_mesh(V, F, cam, np.ones((4, 3)), shading="headlight", ambient=0.2)
    assert lit.rgb[20, 20, 0] == pytest.approx(1.0, abs=1e-3)  # facing the light
    assert lit.rgb[lit.alpha > 0].min() > 0.2


def _scale_cam(c, s):
    return Camera(c.fx * s, c.fy * s, c.cx * s, c.cy * s, c.width * s, c.height * s, c.R, c.t)


def test_errors_name_the_argument():
    cam = _axis_camera()
    V = np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1]])
    with pytest.raises(RenderError, match="colors"):
        render_mesh(V, [[0, 1, 2]], cam, np.ones((2, 3)))
    with pytest.raises(RenderError, match="shading"):
        render_mesh(V, [[0, 1, 2]], cam, shading="phong")
    with pytest.raises(RenderError, match="F indexes"):
        render_mesh(V, [[0, 1, 3]], cam)
    with pytest.raises(RenderError, match="uv"):
        render_mesh(V, [[0, 1, 2]], cam, texture=np.zeros((4, 4, 3)))
