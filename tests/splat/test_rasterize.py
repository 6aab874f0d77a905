import numpy as np
import pytest
import torch

from geoface.errors import GeofaceError
from geoface.camera import Camera, look_at
from geoface.splat.gaussians import Gaussians, GaussianTensors
from geoface.splat.rasterizer import ALPHA_MIN, rasterize, rasterize_reference


def _cam(W=24, H=20, f=30.0):
    return Camera(f, f, W / 2, H / 2, W, H, np.eye(3), np.zeros(3))


def _g(means, s, op, rgb, dtype=torch.float64):
    means = torch.as_tensor(means, dtype=dtype)
    n = len(means)
    return Gaussians(means, torch.full((n, 3), float(np.log(s)), dtype=dtype),
                     torch.tensor([[1.0, 0, 0, 0]] * n, dtype=dtype),
                     torch.logit(torch.as_tensor(op, dtype=dtype)), torch.as_tensor(rgb, dtype=dtype))


def test_single_isotropic_gaussian_closed_form():
    cam = _cam(32, 32, 40.0)
    X, z, s, op = np.array([0.05, -0.03, 2.0]), 2.0, 0.1, 0.8
    g = _g(X[None], s, [op], [[0.2, 0.5, 0.9]])
    rgb, alpha, depth = (a.detach() for a in rasterize(g, cam))
    u, v = 40 * X[0] / z + 16, 40 * X[1] / z + 16
    # isotropic: J W Σ Wᵀ Jᵀ at an off-axis point is not exactly isotropic; compute it exactly
    J = np.array([[40 / z, 0, -40 * X[0] / z**2], [0, 40 / z, -40 * X[1] / z**2]])
    S2 = J @ (s**2 * np.eye(3)) @ J.T + 0.3 * np.eye(2)
    Ci = np.linalg.inv(S2)
    ys, xs = np.mgrid[0:32, 0:32] + 0.5
    d = np.stack([xs - u, ys - v], -1)
    a = op * np.exp(-0.5 * np.einsum("...i,ij,...j", d, Ci, d))
    lam = np.linalg.eigvalsh(S2).max()
    r = np.ceil(3 * np.sqrt(lam))
    a = np.where((np.abs(d[..., 0]) <= r) & (np.abs(d[..., 1]) <= r) & (a >= ALPHA_MIN), np.minimum(a, 0.99), 0)
    np.testing.assert_allclose(alpha.numpy(), a, atol=1e-4)
    np.testing.assert_allclose(rgb.numpy(), a[..., None] * [0.2, 0.5, 0.9], atol=1e-4)
    np.testing.assert_allclose(depth.numpy()[a > 0], z, atol=1e-9)
    # on-axis: the 2D std is exactly f·s/z, variance + 0.3
    g0 = _g([[0, 0, 2.0]], s, [op], [[1.0, 1, 1]])
    al = rasterize(g0, cam)[1].detach().numpy()
    var = (40 * s / 2) ** 2 + 0.3
    x = np.arange(32) + 0.5 - 16
    expect = op * np.exp(-0.5 * (x**2 + 0.25) / var)  # row 15 (v-distance 0.5)
    keep = (expect >= ALPHA_MIN) & (np.abs(x) <= np.ceil(3 * np.sqrt(var)))
    np.testing.assert_allclose(al[15], np.where(keep, expect, 0), atol=1e-4)


def test_two_gaussians_composite_exactly():
    cam = _cam(16, 16, 20.0)
    g = _g([[0.0, 0, 3.0], [0.02, 0.01, 2.0]], 0.15, [0.6, 0.5], [[1.0, 0, 0], [0, 0, 1.0]])
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    rgb, alpha, depth = rasterize(g, cam, background=bg)
    # per-Gaussian alpha images rendered alone (same rules), then composited by hand
    a_far = rasterize(_g([[0.0, 0, 3.0]], 0.15, [0.6], [[1.0, 0, 0]]), cam)[1]
    a_near = rasterize(_g([[0.02, 0.01, 2.0]], 0.15, [0.5], [[0, 0, 1.0]]), cam)[1]
    T1 = 1 - a_near
    C = a_near[..., None] * torch.tensor([0, 0, 1.0]) + T1[..., None] * a_far[..., None] * torch.tensor([1.0, 0, 0])
    T = T1 * (1 - a_far)
    torch.testing.assert_close(rgb, C + T[..., None] * bg, atol=1e-12, rtol=0)
    torch.testing.assert_close(alpha, 1 - T, atol=1e-12, rtol=0)
    D = (a_near * 2.0 + T1 * a_far * 3.0)
    torch.testing.assert_close(depth[alpha > 0], (D / (1 - T))[alpha > 0], atol=1e-12, rtol=0)


def _random_scene(n, seed, sh=False, dtype=torch.float64):
    rng = np.random.default_rng(seed)
    f = lambda *s: torch.tensor(rng.normal(size=s), dtype=dtype)  # noqa: E731
    means = f(n, 3) * 0.5
    means[:, 2] += 3.0
    cols = f(n, 9, 3) * 0.3 if sh else torch.tensor(rng.uniform(size=(n, 3)), dtype=dtype)
    return Gaussians(means, f(n, 3) * 0.4 - 2.3, f(n, 4), f(n) + 1.0, cols)


@pytest.mark.parametrize("seed,sh,tile,chunk", [(0, False, 16, 64), (1, True, 8, 5), (2, False, 7, 3)])
def test_tiled_matches_reference(seed, sh, tile, chunk):
    g = _random_scene(60, seed, sh)
    cam = look_at([0.3, -0.2, -1.0], [0, 0, 3.0], width=45, height=37, fov_y_deg=50)
    bg = torch.tensor([0.3, 0.3, 0.3], dtype=torch.float64)
    out = rasterize(g, cam, background=bg, tile=tile, chunk=chunk)
    ref = rasterize_reference(g, cam, background=bg)
    assert ref[1].max() > 0.5  # a real scene, with overlaps
    for a, b in zip(out, ref):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=0)


def test_behind_camera_culled_and_empty():
    cam = _cam()
    g = _g([[0, 0, -2.0]], 0.3, [0.9], [[1.0, 1, 1]])
    rgb, alpha, depth = rasterize(g, cam)
    assert alpha.abs().max() == 0 and rgb.abs().max() == 0
    rgb, alpha, _ = rasterize_reference(g, cam, background=[1.0, 0, 0])
    assert torch.all(rgb[..., 0] == 1)


def test_gradcheck_tiny_scene():
    g = _random_scene(4, 3, sh=True)
    with torch.no_grad():
        g.means[:, :2] *= 0.3
        g.log_scales += 0.6
        g.opacity_logits.clamp_(-2, 0.5)
    cam = _cam(10, 8, 6.0)
    names = ["means", "log_scales", "quats", "opacity_logits", "colors"]
    params = [getattr(g, n).detach().clone().requires_grad_(True) for n in names]
    w = torch.randn(8, 10, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def f(*ps):
        h = GaussianTensors(*ps)
        rgb, alpha, depth = rasterize(h, cam, tile=4, chunk=2)
        return (torch.cat([rgb, alpha[..., None], depth[..., None]], -1) * w).sum()

    assert rasterize(GaussianTensors(*params), cam)[1].max() > 0.3
    assert torch.autograd.gradcheck(f, params, eps=1e-6, atol=1e-5)
    f(*params).backward()
    for p in params:
        assert p.grad is not None and p.grad.abs().sum() > 0


def test_bad_arguments():
    g = _random_scene(3, 0)
    with pytest.raises(GeofaceError, match="backend"):
        rasterize(g, _cam(), backend="opengl")
    with pytest.raises(GeofaceError, match="Camera"):
        rasterize(g, "cam")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA + gsplat")
def test_gsplat_matches_torch():
    pytest.importorskip("gsplat")
    g = _random_scene(60, 0, dtype=torch.float32)
    cam = look_at([0.3, -0.2, -1.0], [0, 0, 3.0], width=48, height=40)
    ref = rasterize(g, cam, backend="torch")
    out = rasterize(g.cuda(), cam, backend="gsplat")
    torch.testing.assert_close(out[0].cpu(), ref[0], atol=2e-2, rtol=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_torch_path_on_cuda_matches_cpu():
    g = _random_scene(80, 4, sh=True, dtype=torch.float32)
    cam = look_at([0.3, -0.2, -1.0], [0, 0, 3.0], width=45, height=37, fov_y_deg=50)
    gc = GaussianTensors(*(getattr(g, n).detach().cuda().requires_grad_(True)
                           for n in ("means", "log_scales", "quats", "opacity_logits", "colors")))
    for fn in (rasterize, rasterize_reference):
        kw = {"backend": "torch"} if fn is rasterize else {}
        ref = fn(g, cam, background=[0.3, 0.3, 0.3], return_info=True, **kw)
        out = fn(gc, cam, background=[0.3, 0.3, 0.3], return_info=True, **kw)
        for a, b in zip(out[:3], ref[:3]):
            assert a.is_cuda
            torch.testing.assert_close(a.cpu(), b, atol=1e-4, rtol=0)
        assert out[3]["means2d"].is_cuda and torch.equal(out[3]["radii"].cpu(), ref[3]["radii"])
        out[0].sum().backward()
        assert gc.means.grad is not None and gc.means.grad.is_cuda
        gc.means.grad = None


def _uneven_scene(seed=5, dtype=torch.float64):
    """Many overlapping Gaussians crowded into one corner, a few scattered, some large ones."""
    rng = np.random.default_rng(seed)
    n_dense, n_sparse, n_big = 160, 12, 4
    means = np.concatenate([rng.normal([-0.35, -0.3, 3.0], 0.05, (n_dense, 3)),
                            rng.uniform([-0.6, -0.5, 2.5], [0.6, 0.5, 3.5], (n_sparse, 3)),
                            rng.normal([0.1, 0.1, 4.0], 0.2, (n_big, 3))])
    n = len(means)
    ls = np.concatenate([rng.normal(-3.2, 0.3, (n_dense + n_sparse, 3)), rng.normal(-1.3, 0.2, (n_big, 3))])
    t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    return Gaussians(t(means), t(ls), t(rng.normal(size=(n, 4))), t(rng.normal(1.0, 1.5, n)),
                     t(rng.uniform(size=(n, 9, 3)) * 0.4))


@pytest.mark.parametrize("tile,chunk,budget", [(4, 3, 64), (8, 16, 1 << 22), (16, 5, 300), (5, 64, 1000)])
def test_batched_tiles_match_reference_on_uneven_loads(monkeypatch, tile, chunk, budget):
    """Values and gradients of the batched path (tile groups, padding, dropped tiles, the
    hand-written backward) against the all-pairs reference through autograd."""
    import geoface.splat.rasterizer as R
    monkeypatch.setattr(R, "BATCH_ELEMS_CPU", budget)
    g = _uneven_scene()
    cam = look_at([0.0, 0.0, -1.0], [0, 0, 3.0], width=45, height=37, fov_y_deg=50)
    names = ["means", "log_scales", "quats", "opacity_logits", "colors"]
    ws = torch.rand(37, 45, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    grads = []
    for fn, kw in ((rasterize, {"tile": tile, "chunk": chunk}), (rasterize_reference, {})):
        ps = [getattr(g, n).detach().clone().requires_grad_(True) for n in names]
        out = fn(GaussianTensors(*ps), cam, background=[0.2, 0.5, 0.1], **kw)
        (torch.cat([out[0], out[1][..., None], out[2][..., None]], -1) * ws).sum().backward()
        grads.append((out, [p.grad for p in ps]))
    (out, ga), (ref, gr) = grads
    _, _, counts, _, _ = R._bin(*(lambda p: (p[0], p[3], p[1]))(R._prepare(g, cam, 0.01)), 45, 37, tile)
    nz = counts[counts > 0]
    assert nz.max() > 10 * max(int(nz.min()), 1)  # loads differ by more than 10×
    assert ref[1].max() > 0.99 and (ref[1] > 0.5).float().mean() > 0.03  # saturated corner
    for a, b in zip(out, ref):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=0)
    for name, a, b in zip(names, ga, gr):
        torch.testing.assert_close(a, b, atol=1e-7, rtol=1e-6, msg=name)


def test_auto_tile_and_default_matches_reference():
    from geoface.splat.rasterizer import auto_tile
    assert auto_tile(torch.tensor([0, 3, 4, 5])) == 4
    assert auto_tile(torch.tensor([12, 20, 0])) == 8
    assert auto_tile(torch.tensor([50, 60])) == 16 and auto_tile(torch.zeros(3, dtype=torch.int64)) == 16
    g = _uneven_scene()
    cam = look_at([0.0, 0.0, -1.0], [0, 0, 3.0], width=45, height=37, fov_y_deg=50)
    for a, b in zip(rasterize(g, cam), rasterize_reference(g, cam)):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
