import numpy as np
import pytest

from geoface.skin import SkinError

from geoface.errors import LearnError
from geoface.texture.synth import height_to_normal, random_lights, shade, skin_maps


def test_deterministic_ranges_and_layout():
    a, b = skin_maps(128, seed=5), skin_maps(128, seed=5)
    assert np.array_equal(a.stack(), b.stack())
    assert not np.array_equal(a.albedo, skin_maps(128, seed=6).albedo)
    s = a.stack()
    assert s.shape == (128, 128, 7) and s.dtype == np.float32
    assert s.min() >= 0 and s.max() <= 1
    n = a.micronormal * 2 - 1
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1, atol=1e-6)
    assert (n[..., 2] > 0.3).all()
    with pytest.raises(SkinError):
        skin_maps(8)


def test_same_skin_at_two_resolutions():
    lo, hi = skin_maps(128, seed=2).albedo, skin_maps(512, seed=2).albedo
    down = hi.reshape(128, 4, 128, 4, 3).mean((1, 3))
    # low-frequency content agrees (8x8-texel blocks), far below the variation between seeds
    blk = lambda x: x.reshape(16, 8, 16, 8, 3).mean((1, 3))  # noqa: E731
    err = np.abs(blk(lo) - blk(down)).mean()
    other = np.abs(blk(lo) - blk(skin_maps(128, seed=3).albedo)).mean()
    assert err < 0.05 * other


def test_height_to_normal_of_a_ramp():
    R = 64
    u = np.arange(R)[None, :] / R
    h = np.broadcast_to(0.1 * u, (R, R)).copy()
    n = height_to_normal(h, 1.0) * 2 - 1
    expect = np.array([-0.1, 0.0, 1.0]) / np.hypot(0.1, 1.0)
    np.testing.assert_allclose(n[:, 1:-1], np.broadcast_to(expect, (R, R - 2, 3)), atol=1e-9)


def test_shade_lambert_closed_form():
    alb = np.array([[0.5, 0.4, 0.3]])
    flat = np.array([[0.5, 0.5, 1.0]])
    N = np.array([[0.0, 0.0, 1.0]])
    lights = (np.array([[0.0, 0.6, 0.8]]), np.array([[1.0, 1.0, 1.0]]), np.array([0.1, 0.1, 0.1]))
    out = shade(alb, flat, np.zeros((1, 1)), N, N, lights, gamma=1.0)
    np.testing.assert_allclose(out, alb * (0.1 + 0.8), atol=1e-12)
    # a specular map adds light, most along the mirror direction
    lights = (np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 1.0, 1.0]]), np.zeros(3))
    s0 = shade(alb, flat, np.zeros((1, 1)), N, N, lights, gamma=1.0)
    s1 = shade(alb, flat, np.ones((1, 1)), N, N, lights, gamma=1.0)
    assert (s1 > s0).all()
    # a tilted micronormal changes diffuse shading
    tilt = np.array([[0.5 + 0.3, 0.5, 0.5 + 0.5 * np.sqrt(1 - 0.36)]])
    s2 = shade(alb, tilt, np.zeros((1, 1)), N, N, lights, gamma=1.0)
    np.testing.assert_allclose(s2, alb * np.sqrt(1 - 0.36), atol=1e-9)


def test_random_lights_face_the_camera():
    d, c, amb = random_lights(np.random.default_rng(0), 5)
    assert d.shape == (5, 3) and (d[:, 2] > 0).all() and np.allclose(np.linalg.norm(d, axis=1), 1)
    assert (c > 0).all() and amb.shape == (3,)


def test_render_sample_of_a_uv_square():
    from geoface.texture.synth import render_skin_sample
    from geoface.splat import look_at
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = V[:, :2].copy()
    maps = skin_maps(64, seed=0)
    cam = look_at((0.5, 0.5, 2.0), (0.5, 0.5, 0.0), width=48, height=48, fov_y_deg=40)
    lights = (np.array([[0.0, 0.0, 1.0]]), np.ones((1, 3)), np.zeros(3))
    s = render_skin_sample(V, F, UV, maps, cam, lights)
    m = s["mask"]
    assert 0.2 < m.mean() < 0.9 and s["photo"].shape == (48, 48, 3)
    # UV of a covered pixel = the world point its ray hits (the square is the UV square)
    i, j = 24, 30
    assert m[i, j]
    ray_uv, _ = cam.project(np.array([[s["uv"][i, j, 0], s["uv"][i, j, 1], 0.0]]))
    np.testing.assert_allclose(ray_uv[0], [j + 0.5, i + 0.5], atol=1e-6)
    # a surface facing the camera: camera-space normal −z, encoded (0.5, 0.5, 0)
    np.testing.assert_allclose(s["normal"][m], np.broadcast_to([0.5, 0.5, 0.0], (m.sum(), 3)), atol=1e-6)
    assert s["maps"][m].min() >= 0 and s["maps"][m].max() <= 1
    assert (s["photo"][~m] == 0).all() and (s["maps"][~m] == 0).all()
    # flat skin, no specular, light along the normal: photo = albedo^(1/2.2) exactly
    from geoface.texture.synth import SkinMaps
    R = 64
    alb = np.stack([*np.meshgrid(np.linspace(0.1, 0.9, R), np.linspace(0.2, 0.6, R)), np.full((R, R), 0.5)], -1)
    flat = SkinMaps(alb, np.zeros((R, R)), np.broadcast_to([0.5, 0.5, 1.0], (R, R, 3)).copy(), np.zeros((R, R, 1)))
    s = render_skin_sample(V, F, UV, flat, cam, lights)
    np.testing.assert_allclose(s["photo"][m], s["maps"][m][:, :3] ** (1 / 2.2), atol=1e-5)


def test_make_texture_dataset(tmp_path):
    from geoface.texture.synth import make_texture_dataset
    from geoface.texture.model import load_sample
    paths = make_texture_dataset(tmp_path, count=2, res=64, map_res=128, vertices=3000, quiet=True)
    d = load_sample(paths[0])
    assert d["photo"].shape == (64, 64, 3) and 0.2 < d["mask"].mean() < 0.95
    # a near-frontal camera sees normals pointing back at it (camera −z → encoded z < 0.5)
    assert np.median(d["normal"][d["mask"]][:, 2]) < 0.3
    before = paths[1].stat().st_mtime_ns
    make_texture_dataset(tmp_path, count=2, res=64, map_res=128, vertices=3000, quiet=True)
    assert paths[1].stat().st_mtime_ns == before  # resumable: nothing rewritten
    with pytest.raises(LearnError):
        make_texture_dataset(tmp_path, count=0)


def test_make_texture_dataset_workers_write_the_same_files(tmp_path):
    from geoface.texture.synth import make_texture_dataset
    a = make_texture_dataset(tmp_path / "a", count=2, res=48, map_res=64, vertices=2000, quiet=True)
    b = make_texture_dataset(tmp_path / "b", count=2, res=48, map_res=64, vertices=2000, workers=2, quiet=True)
    for pa, pb in zip(a, b):
        with np.load(pa) as za, np.load(pb) as zb:
            for k in za.files:
                assert np.array_equal(za[k], zb[k]), k


def test_unweld_uv_keeps_every_corner():
    from geoface.texture.synth import unweld_uv
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = np.array([[0, 0], [1, 0], [1, 1], [0.5, 0.5], [0, 1]], float)
    FUV = np.array([[0, 1, 2], [3, 2, 4]])  # vertex 0 has two UVs (a seam)
    V2, F2, UV2 = unweld_uv(V, F, UV, FUV)
    assert len(V2) == 5 and np.allclose(V2[F2], V[F]) and np.allclose(UV2[F2], UV[FUV])


def test_ict_texture_samples(tmp_path):
    """``head_source="ict"``: ICT people with regional skin; the mask keeps the face tile only
    and covers a near-frontal face; maps and photo are defined there."""
    from geoface.texture.synth import make_texture_dataset
    from geoface.texture.model import load_sample
    p = make_texture_dataset(tmp_path, count=1, res=96, map_res=256, seed=5, head_source="ict", quiet=True)
    s = load_sample(p[0])
    m = s["mask"]
    assert 0.15 < m.mean() < 0.9
    assert (s["uv"][m] >= 0).all() and (s["uv"][m] <= 1).all()
    assert s["photo"][m].mean() > 0.05 and s["maps"][m][:, 0:3].std() > 0.005
    with pytest.raises(LearnError, match="head_source"):
        make_texture_dataset(tmp_path / "x", count=1, res=64, head_source="flame")


def test_random_lights_share_a_total_power():
    for s in range(20):
        d, c, amb = random_lights(np.random.default_rng(s), 4, power=(1.0, 1.0))
        total = c.mean(1).sum() + amb[0]  # the ±15 % tint averages out over channels only roughly
        assert 0.85 < total < 1.15, total
        assert (c > 0).all() and 0.04 < amb[0] < 0.16


def test_eye_albedo_pupil_iris_sclera():
    from geoface.texture.synth import eye_albedo
    iris = np.array([0.2, 0.3, 0.45])
    c = np.cos(np.radians([0.0, 20.0, 60.0]))
    a = eye_albedo(c, iris, pupil_deg=12, iris_deg=30)
    assert np.allclose(a[0], 0.02)  # the pupil
    assert np.argmax(a[1]) == 2 and a[1].max() < 0.5  # the (blue) iris
    assert a[2].min() > 0.6  # the sclera


def test_ict_samples_show_eyes_outside_the_mask(tmp_path):
    """ICT photos have eyes (a dark pupil and a white sclera between the eyelid landmarks),
    which the skin mask leaves out; the 68 landmarks are stored in pixels."""
    from geoface.texture.synth import make_texture_dataset
    from geoface.texture.model import load_sample
    [p] = make_texture_dataset(tmp_path, count=1, res=256, map_res=256, seed=2, head_source="ict", quiet=True)
    s = load_sample(p)
    with np.load(p) as z:
        L = z["landmarks"]
    assert L.shape == (68, 2) and (L > 0).all() and (L < 256).all()
    for eye in (slice(36, 42), slice(42, 48)):  # each eye's six eyelid points
        lo, hi = np.floor(L[eye].min(0)).astype(int), np.ceil(L[eye].max(0)).astype(int)
        box = (slice(lo[1], hi[1] + 1), slice(lo[0], hi[0] + 1))
        photo, mask = s["photo"][box], s["mask"][box]
        assert (~mask).mean() > 0.4  # mostly not skin
        grey = photo[~mask].mean(1)
        assert grey.min() < 0.25 and grey.max() - grey.min() > 0.4, (grey.min(), grey.max())  # pupil and sclera
    # the nose tip (landmark 30) is skin
    x, y = np.round(L[30]).astype(int)
    assert s["mask"][y, x]


def test_pixel_average_is_what_a_camera_integrates():
    from geoface.texture.synth import pixel_average
    H = 4
    photo = np.zeros((H, H, 3), np.float32)
    photo[0, 0] = 1.0  # one bright sub-pixel of four: a quarter of the light
    n = np.zeros((H, H, 3))
    n[..., 2] = 1.0
    n[0, 0] = [1.0, 0.0, 0.0]  # one sub-pixel's normal of four tilted 90°: the mean is (1, 0, 3)/√10
    s = {"photo": photo, "maps": np.concatenate([np.full((H, H, 3), 0.4), n * 0.5 + 0.5, np.full((H, H, 1), 0.2)], -1),
         "uv": np.random.default_rng(0).random((H, H, 2)), "normal": n * 0.5 + 0.5, "mask": np.ones((H, H), bool)}
    s["mask"][3, 3] = False
    out = pixel_average(s, 2)
    assert out["photo"].shape == (2, 2, 3)
    np.testing.assert_allclose(out["photo"][0, 0], 0.25 ** (1 / 2.2), rtol=1e-6)  # linear light, re-encoded
    np.testing.assert_allclose(out["normal"][0, 0] * 2 - 1, np.array([1, 0, 3]) / np.sqrt(10), atol=1e-6)
    np.testing.assert_allclose(out["maps"][0, 0, 3:6] * 2 - 1, np.array([1, 0, 3]) / np.sqrt(10), atol=1e-6)
    np.testing.assert_allclose(out["maps"][0, 1], [0.4, 0.4, 0.4, 0.5, 0.5, 1.0, 0.2], atol=1e-6)
    np.testing.assert_allclose(out["uv"][0, 0], s["uv"][:2, :2].mean((0, 1)), atol=1e-6)
    assert out["mask"].tolist() == [[True, True], [True, False]]  # a block with a background sub-pixel is out
    assert (out["maps"][1, 1] == 0).all()


@pytest.mark.parametrize("shape,R", [((400, 400), 16), ((250, 1700), 20), ((3334, 3334), 64)])
def test_the_noise_blurred_where_a_small_map_reads_it_is_the_whole_blur_there(shape, R):
    """A small map of a fine noise grid blurs only the cells its resampling reads: the same numbers,
    to the last bit, as the whole grid's blur, and so the same map."""
    from scipy import ndimage

    from geoface.skin.render import NOISE_BLUR, _blurred_where_read

    noise = np.random.default_rng(3).standard_normal(shape)
    part, whole = _blurred_where_read(noise, R), ndimage.gaussian_filter(noise, NOISE_BLUR, mode="wrap")
    read = part != 0
    assert read.sum() >= (2 * R) ** 2 and np.array_equal(part[read], whole[read])
    zoom = dict(zoom=(R / shape[0], R / shape[1]), order=1, mode="grid-wrap", grid_mode=True)
    assert np.array_equal(ndimage.zoom(part, **zoom), ndimage.zoom(whole, **zoom))
