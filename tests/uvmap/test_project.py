"""Photo → UV projection: a synthetic camera photographs an analytic colour; projecting the photo
back reproduces it where visible; occluded and back-facing texels get weight 0 and the default."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError, InvalidMeshError
from geoface.mesh.io import Mesh
from geoface.synth import square_grid
from geoface.uvmap import Camera, depth_buffer, project_views

# three axis-aligned quads: (x range, y range, z, facing +z?, UV box u0, v0, size)
QUADS = [
    ((-1.0, 1.0), (-1.0, 1.0), 0.0, True, (0.0, 0.0, 0.5)),  # back wall
    ((-0.3, 0.3), (-0.3, 0.3), 1.0, True, (0.5, 0.0, 0.25)),  # occluder in front of it
    ((1.05, 1.35), (-0.3, 0.3), 0.2, False, (0.5, 0.5, 0.25)),  # faces away from the camera
]
H = W = 200
K = np.array([[250.0, 0, 99.5], [0, 250.0, 99.5], [0, 0, 1]])
R0 = np.diag([1.0, -1.0, -1.0])  # looking down world -z, image y = world -y


def _camera(center):
    return Camera.from_K(K, R0, -R0 @ np.asarray(center, float))


def _scene():
    Vs, Fs, UVs, ids = [], [], [], []
    off = 0
    for k, ((x0, x1), (y0, y1), z, up, (u0, v0, s)) in enumerate(QUADS):
        g, F = square_grid(9)
        V = np.column_stack([x0 + (x1 - x0) * g[:, 0], y0 + (y1 - y0) * g[:, 1], np.full(len(g), z)])
        UV = np.column_stack([u0 + s * (0.02 + 0.96 * g[:, 0]), v0 + s * (0.02 + 0.96 * g[:, 1])])
        if not up:
            F = F[:, ::-1]
        Vs.append(V), Fs.append(F + off), UVs.append(UV), ids.append(np.full(len(F), k))
        off += len(V)
    V, F, UV = np.concatenate(Vs), np.concatenate(Fs), np.concatenate(UVs)
    return Mesh(V, F, UV=UV, FUV=F), np.concatenate(ids)


def _color(X):
    return np.column_stack([0.5 + 0.3 * np.sin(1.5 * X[:, 0]), 0.5 + 0.3 * np.cos(1.3 * X[:, 1]),
                            0.4 + 0.2 * X[:, 0] * X[:, 1]])


def _photo(cam):
    """Ray-cast the quads through the pixel centres (j + 0.5, i + 0.5): colour and quad id per
    pixel (-1 = background)."""
    v, u = np.mgrid[0:H, 0:W]
    d = np.column_stack([u.ravel() + 0.5, v.ravel() + 0.5, np.ones(H * W)]) @ np.linalg.inv(K).T @ cam.R  # world dirs
    c = cam.center
    best = np.full(H * W, np.inf)
    hit = np.full(H * W, -1)
    col = np.zeros((H * W, 3))
    for k, ((x0, x1), (y0, y1), z, _, _) in enumerate(QUADS):
        t = (z - c[2]) / d[:, 2]
        X = c + t[:, None] * d
        ok = (t > 0) & (t < best) & (X[:, 0] >= x0) & (X[:, 0] <= x1) & (X[:, 1] >= y0) & (X[:, 1] <= y1)
        best[ok], hit[ok], col[ok] = t[ok], k, _color(X[ok])
    return col.reshape(H, W, 3), hit.reshape(H, W)


@pytest.fixture(scope="module")
def scene():
    return _scene()


def _texel_quads(mesh, ids, T):
    from geoface.gimage import rasterize_faces
    face, _ = rasterize_faces(mesh.FUV, mesh.UV, T)
    return np.where(face >= 0, ids[np.maximum(face, 0)], -1)


def test_projection_reproduces_the_photographed_colour(scene):
    mesh, ids = scene
    cam = _camera([0.0, 0.0, 4.0])
    photo, hit = _photo(cam)
    T = 128
    res = project_views(mesh, photo, cam, T, default=(1.0, 0.0, 1.0))
    from geoface.uvmap import texel_geometry
    P, _, cover = texel_geometry(mesh, T)
    q = _texel_quads(mesh, ids, T)
    seen = res.weight > 0
    # visible texels: their colour; only compare where the photo's 3×3 pixels around the
    # projection all show the texel's own quad (no silhouette mixing)
    pix, z = cam.project(P[seen])
    r, c = np.round(pix[:, 1]).astype(int), np.round(pix[:, 0]).astype(int)
    clean = np.ones(len(r), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            clean &= hit[np.clip(r + dr, 0, H - 1), np.clip(c + dc, 0, W - 1)] == q[seen]
    err = np.abs(res.texture[seen][clean] - _color(P[seen][clean]))
    assert clean.sum() > 0.8 * seen.sum()
    assert err.max() < 2e-3
    # weights are cos(θ)^2 toward the camera centre
    view = cam.center - P[seen]
    cos = view[:, 2] / np.linalg.norm(view, axis=1)
    assert np.allclose(res.weight[seen], cos**2)
    # occluded part of the back wall (behind the front quad: |x|, |y| < 0.4) and back-facing quad
    back = (q == 0) & (np.abs(P[..., 0]) < 0.37) & (np.abs(P[..., 1]) < 0.37)
    free = (q == 0) & (np.maximum(np.abs(P[..., 0]), np.abs(P[..., 1])) > 0.43)
    assert back.sum() > 50 and free.sum() > 500
    assert (res.weight[back] == 0).all() and (res.weight[free] > 0).all()
    assert (res.weight[q == 1] > 0).all()
    assert (res.weight[q == 2] == 0).all() and (q == 2).sum() > 50
    unseen = ~seen
    assert np.array_equal(res.texture[unseen], np.broadcast_to([1.0, 0.0, 1.0], (int(unseen.sum()), 3)))
    assert (res.weight[~cover] == 0).all()


def test_two_views_blend_and_fill_more(scene):
    mesh, _ = scene
    cams = [_camera([0.0, 0.0, 4.0]), _camera([1.5, 0.0, 4.0])]
    photos = [_photo(c)[0] for c in cams]
    T = 96
    one = project_views(mesh, photos[0], cams[0], T)
    two = project_views(mesh, photos, cams, T, power=1.0)
    assert np.allclose(two.per_view.sum(0), two.weight)
    assert (two.weight > 0).sum() > (one.weight > 0).sum()  # the second view sees behind the occluder
    from geoface.uvmap import texel_geometry
    P, _, _ = texel_geometry(mesh, T)
    both = (two.per_view > 0).all(0)
    err = np.abs(two.texture[both] - _color(P[both]))
    assert both.sum() > 500 and np.median(err) < 1e-3
    # uint8 photos are read as /255
    u8 = project_views(mesh, np.round(photos[0] * 255).astype(np.uint8), cams[0], T)
    assert np.abs(u8.texture - one.texture).max() < 1.0 / 255 + 1e-9


def test_depth_buffer_of_a_tilted_plane_is_perspective_correct():
    V, F = square_grid(5, 1.0)
    V = V - [0.5, 0.5, 0.0]
    V[:, 2] = 0.4 * V[:, 0]  # tilted: the depth varies non-linearly across the image
    cam = _camera([0.0, 0.0, 3.0])
    z = depth_buffer(V, F, cam, (H, W))
    v, u = np.nonzero(np.isfinite(z))
    assert 2000 < len(u) < H * W / 4 and not np.isfinite(z[0, 0])  # ±0.5 at depth ~3 → ~42 px
    d = np.column_stack([u + 0.5, v + 0.5, np.ones(len(u))]) @ np.linalg.inv(K).T @ cam.R  # pixel centres
    t = cam.center[2] / (0.4 * d[:, 0] - d[:, 2])  # ray ∩ plane z = 0.4 x
    X = cam.center + t[:, None] * d
    assert np.allclose(z[v, u], cam.center[2] - X[:, 2], atol=1e-9)


def test_bad_inputs_raise(scene):
    mesh, _ = scene
    cam = _camera([0, 0, 4.0])
    img = np.zeros((20, 20, 3))
    with pytest.raises(GeofaceError, match="K"):
        Camera.from_K(np.eye(2), np.eye(3), np.zeros(3))
    with pytest.raises(GeofaceError, match="rotation"):
        Camera.from_K(K, 2 * np.eye(3), np.zeros(3))
    with pytest.raises(GeofaceError, match="extrinsics"):
        Camera.from_matrix(K, np.eye(3))
    assert np.allclose(Camera.from_matrix(K, np.vstack([np.column_stack([R0, cam.t]), [0, 0, 0, 1]])).center, cam.center)
    with pytest.raises(GeofaceError, match="one image per camera"):
        project_views(mesh, [img, img], cam, 16)
    with pytest.raises(GeofaceError, match=r"images\[0\]"):
        project_views(mesh, np.zeros((20, 20, 2)), cam, 16)
    bad = img.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(GeofaceError, match="NaN"):
        project_views(mesh, bad, cam, 16)
    with pytest.raises(GeofaceError, match="default"):
        project_views(mesh, img, cam, 16, default=(1.0, 2.0))
    with pytest.raises(InvalidMeshError, match="UVs"):
        project_views(Mesh(mesh.V, mesh.F), img, cam, 16)
    with pytest.raises(GeofaceError, match="cameras"):
        project_views(mesh, img, "camera", 16)


def test_a_render_projects_back_onto_its_own_texture_without_a_half_pixel_shift():
    """geoface's renderer, its tracker and the photo projection share one pixel convention
    (centres at j + 0.5): a checkerboard rendered by render_mesh projects back onto the texture
    it was rendered with; the same camera moved by half a pixel does measurably worse."""
    from dataclasses import replace

    from geoface.nn import render_mesh

    g, F = square_grid(2)
    V = np.column_stack([g[:, 0] - 0.5, g[:, 1] - 0.5, np.zeros(len(g))])
    UV = g[:, :2].copy()
    T = 64
    i, j = np.mgrid[0:T, 0:T]
    tex = np.repeat((((i // 8) + (j // 8)) % 2)[:, :, None].astype(float), 3, 2)
    cam = Camera(200.0, 200.0, 64.0, 64.0, 128, 128, R0, -R0 @ np.array([0.0, 0.0, 2.0]))
    photo = render_mesh(V, F, cam, uv=UV, texture=tex).rgb
    mesh = Mesh(V, F, UV=UV, FUV=F)
    err = []
    for c in (cam, replace(cam, cx=cam.cx + 0.5, cy=cam.cy + 0.5)):
        res = project_views(mesh, photo, c, T)
        assert (res.weight > 0).all()
        err.append(np.abs(res.texture - tex).mean())
    assert err[0] < 0.055 and err[1] > 1.4 * err[0]  # measured 0.050 and 0.079
