import math

import numpy as np
import pytest
import torch

from geoface.errors import GeofaceError
from geoface.camera import Camera
from geoface.splat.density import (PARAM_NAMES, DensityConfig, DensityStrategy, keep_gaussians,
                                   make_optimizer)
from geoface.splat.gaussians import Gaussians
from geoface.splat.rasterizer import rasterize, rasterize_reference


def _gs(means, scale, opacity=0.5, parent=None, quats=None):
    means = torch.as_tensor(means, dtype=torch.float32)
    n = len(means)
    ls = torch.log(torch.as_tensor(scale, dtype=torch.float32).expand(n, 3).clone())
    q = torch.tensor([[1.0, 0, 0, 0]] * n) if quats is None else torch.as_tensor(quats, dtype=torch.float32)
    op = torch.logit(torch.as_tensor(opacity, dtype=torch.float32).expand(n).clone())
    return Gaussians(means, ls, q, op, torch.rand(n, 3, generator=torch.Generator().manual_seed(0)),
                     parent=torch.arange(n) + 100 if parent is None else parent)


def _info(grads, radii=None, W=64, H=48):
    """A fake rasterizer info whose means2d carries the given pixel-space gradient."""
    g = torch.as_tensor(grads, dtype=torch.float32)
    m = torch.zeros_like(g, requires_grad=True)
    m.grad = g.clone()
    r = torch.full((len(g),), 3, dtype=torch.int64) if radii is None else torch.as_tensor(radii)
    return {"means2d": m, "radii": r, "width": W, "height": H}


def _cam(W=32, H=32, f=32.0):
    return Camera(f, f, W / 2, H / 2, W, H, np.eye(3), np.zeros(3))


def test_clone_small_gaussian_with_large_gradient():
    g = _gs([[0, 0, 2.0], [0.1, 0, 2.0], [0.2, 0, 2.0]], 0.001)
    s = DensityStrategy(DensityConfig(grad_threshold=2e-4), scene_extent=1.0)
    # pixel gradient 1e-5 → NDC norm 1e-5·32 = 3.2e-4 ≥ 2e-4 for Gaussian 0 only
    s.update_state(g, _info([[1e-5, 0], [1e-6, 0], [0, 0]]))
    out = s.densify(g, None)
    assert out == {"cloned": 1, "split": 0, "pruned": 0} and len(g) == 4
    for name in PARAM_NAMES:
        torch.testing.assert_close(getattr(g, name)[3], getattr(g, name)[0])
    assert g.parent.tolist() == [100, 101, 102, 100]
    assert s.grad2d.shape == (4,) and float(s.grad2d.abs().sum()) == 0  # statistics restart


def test_gradient_is_a_mean_over_visible_views():
    g = _gs([[0, 0, 2.0]], 0.001)
    s = DensityStrategy(scene_extent=1.0)
    s.update_state(g, _info([[1e-5, 0]]))
    s.update_state(g, _info([[1.0, 0]], radii=[0]))  # not visible: ignored
    s.update_state(g, _info([[0, 0]]))
    assert s.count.item() == 2
    assert s.grad2d.item() / s.count.item() == pytest.approx(1e-5 * 32 / 2)
    assert s.densify(g, None)["cloned"] == 0  # mean 1.6e-4 < 2e-4


def test_split_children_sample_the_parent_distribution():
    torch.manual_seed(0)
    q = torch.tensor([[math.cos(0.4), 0.3, -0.5, math.sin(0.4)]])
    g = Gaussians(torch.tensor([[0.3, -0.2, 2.0]]), torch.log(torch.tensor([[0.2, 0.05, 0.1]])), q,
                  torch.tensor([0.7]), torch.tensor([[0.1, 0.2, 0.3]]), parent=torch.tensor([7]))
    cov = g.covariances()[0].detach().double()
    k = 20000
    s = DensityStrategy(DensityConfig(split_n=k), scene_extent=1.0)
    assert s.split(g, None, torch.tensor([0])) == 1
    assert len(g) == k  # the parent is replaced by its children
    x = g.means.detach().double()
    se = torch.sqrt(torch.diagonal(cov)) / math.sqrt(k)
    assert torch.all((x.mean(0) - torch.tensor([0.3, -0.2, 2.0], dtype=torch.float64)).abs() < 4 * se)
    torch.testing.assert_close(torch.cov(x.T), cov, atol=3e-4, rtol=0.05)
    torch.testing.assert_close(g.log_scales.detach()[0], torch.log(torch.tensor([0.2, 0.05, 0.1]) / 1.6))
    assert torch.all(g.parent == 7) and torch.all(g.opacity_logits == 0.7)


def test_densify_splits_large_and_clones_small():
    torch.manual_seed(1)
    g = _gs([[0, 0, 2.0], [0.1, 0, 2.0], [0.2, 0, 2.0]], [0.001, 0.001, 0.001])
    with torch.no_grad():
        g.log_scales[1] = math.log(0.05)  # > percent_dense · extent = 0.01
    s = DensityStrategy(scene_extent=1.0)
    s.update_state(g, _info([[1e-4, 0], [0, 1e-4], [0, 0]]))
    out = s.densify(g, None)
    assert (out["cloned"], out["split"], out["pruned"]) == (1, 1, 0)
    assert len(g) == 3 + 1 + 2 - 1
    assert sorted(g.parent.tolist()) == [100, 100, 101, 101, 102]
    kids = g.parent == 101
    torch.testing.assert_close(g.log_scales.detach()[kids], torch.full((2, 3), math.log(0.05 / 1.6)))


def test_prune_transparent_then_big_after_reset():
    g = _gs([[0, 0, 2.0], [0.1, 0, 2.0], [0.2, 0, 2.0], [0.3, 0, 2.0]], 0.001)
    with torch.no_grad():
        g.opacity_logits[0] = torch.logit(torch.tensor(0.001))
        g.log_scales[1] = math.log(0.5)  # > 0.1 · extent
    s = DensityStrategy(scene_extent=1.0)
    s.update_state(g, _info(torch.zeros(4, 2), radii=[2, 2, 2, 50]))
    assert s.prune_mask(g).tolist() == [True, False, False, False]  # before any reset
    s.n_resets = 1
    assert s.prune_mask(g).tolist() == [True, True, False, True]
    assert s.prune(g, None) == 3 and g.parent.tolist() == [102]


def test_max_gaussians_cap_takes_largest_gradients():
    g = _gs([[0, 0, 2.0], [0.1, 0, 2.0], [0.2, 0, 2.0]], 0.001)
    s = DensityStrategy(DensityConfig(max_gaussians=4), scene_extent=1.0)
    s.update_state(g, _info([[1e-4, 0], [3e-4, 0], [2e-4, 0]]))
    assert s.densify(g, None)["cloned"] == 1 and g.parent.tolist() == [100, 101, 102, 101]


def _train_setup(n=30, seed=0):
    rng = np.random.default_rng(seed)
    means = np.c_[rng.uniform(-0.4, 0.4, (n, 2)), np.full(n, 2.0)]
    g = _gs(means, 0.03, opacity=0.6)
    return g, make_optimizer(g, {"means": 1e-3})


def _loss_step(g, opt, cam, target):
    rgb, alpha, depth, info = rasterize(g, cam, return_info=True)
    loss = (rgb - target).abs().mean()
    opt.zero_grad()
    info["means2d"].retain_grad()
    loss.backward()
    opt.step()
    return loss.item(), info


def test_optimizer_state_follows_densification_and_training_continues():
    torch.manual_seed(0)
    g, opt = _train_setup()
    cam = _cam()
    target = torch.zeros(32, 32, 3)
    target[8:20, 10:24, 0] = 1.0
    _, info = _loss_step(g, opt, cam, target)
    before = {n: opt.state[getattr(g, n)]["exp_avg"].clone() for n in PARAM_NAMES}
    s = DensityStrategy(DensityConfig(grad_threshold=1e-12, percent_dense=0.05), scene_extent=1.0)
    s.update_state(g, info)
    grown = torch.zeros(len(g), dtype=torch.bool)
    grown[s.grad2d > 0] = True
    n0 = len(g)
    out = s.densify(g, opt)
    assert out["cloned"] == int(grown.sum()) > 0 and len(g) == n0 + out["cloned"]
    for grp in opt.param_groups:
        p = grp["params"][0]
        assert p is getattr(g, grp["name"])
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape
        torch.testing.assert_close(st["exp_avg"][:n0], before[grp["name"]])  # old rows kept
        assert float(st["exp_avg"][n0:].abs().sum()) == 0  # new rows start at zero
    keep = torch.ones(len(g), dtype=torch.bool)
    keep[::3] = False
    ref = {n: opt.state[getattr(g, n)]["exp_avg_sq"][keep].clone() for n in PARAM_NAMES}
    keep_gaussians(g, opt, keep)
    for n in PARAM_NAMES:
        torch.testing.assert_close(opt.state[getattr(g, n)]["exp_avg_sq"], ref[n])
    loss0 = _loss_step(g, opt, cam, target)[0]
    for _ in range(5):
        loss = _loss_step(g, opt, cam, target)[0]
    assert np.isfinite(loss) and loss < loss0


def test_opacity_reset_on_schedule():
    g, opt = _train_setup()
    cam = _cam()
    _, info = _loss_step(g, opt, cam, torch.zeros(32, 32, 3))
    s = DensityStrategy(DensityConfig(reset_every=10, refine_start=100), scene_extent=1.0)
    assert s.step_post_backward(g, opt, info, 9)["reset"] is False
    _, info = _loss_step(g, opt, cam, torch.zeros(32, 32, 3))
    out = s.step_post_backward(g, opt, info, 10)
    assert out["reset"] and s.n_resets == 1
    assert float(g.opacities().detach().max()) <= 0.01 + 1e-6
    assert float(opt.state[g.opacity_logits]["exp_avg"].abs().sum()) == 0


class _NoChildrenAbovePlane(DensityStrategy):
    """HFM-GS-like constraint: drop split children above the plane y = 0."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.added, self.pruned = [], []

    def filter_split(self, gaussians, parent_idx, child_params):
        return child_params["means"][:, 1] <= 0.0

    def on_added(self, gaussians, src_idx, n_new):
        self.added.append((src_idx.clone(), n_new))

    def on_pruned(self, gaussians, keep):
        self.pruned.append(keep.clone())


def test_subclass_hook_vetoes_children():
    torch.manual_seed(0)
    # Gaussian 0 straddles y = 0; Gaussian 1 lies far above it (all children vetoed → kept)
    g = _gs([[0, 0, 2.0], [0, 5.0, 2.0]], 0.2)
    s = _NoChildrenAbovePlane(DensityConfig(split_n=200), scene_extent=1.0)
    assert s.split(g, None, torch.tensor([0, 1])) == 1
    assert g.parent[0].item() == 101 and g.means[0, 1].item() == 5.0  # vetoed parent stays
    kids = g.means.detach()[1:]
    assert 50 < len(kids) < 150 and torch.all(kids[:, 1] <= 0)
    assert torch.all(g.parent[1:] == 100)
    assert s.added[0][1] == len(kids) and torch.all(s.added[0][0] == 0)
    assert s.pruned[0].tolist()[:2] == [False, True]


def test_return_info_means2d_gradient_and_radii():
    g = _gs([[0, 0, 2.0], [0.05, 0.02, 2.5], [0, 0, -1.0]], 0.05)
    cam = _cam()
    for fn in (rasterize, rasterize_reference):
        out = fn(g, cam, return_info=True)
        assert len(out) == 4 and len(fn(g, cam)) == 3
        info = out[3]
        assert info["means2d"].shape == (3, 2) and (info["width"], info["height"]) == (32, 32)
        assert info["radii"].tolist()[2] == 0 and min(info["radii"].tolist()[:2]) > 0
        info["means2d"].retain_grad()
        (out[0][:, :16].sum()).backward()  # moving right brightens the left half less
        gm = info["means2d"].grad
        assert gm[0, 0] < 0 and float(gm[2].abs().sum()) == 0
        g.zero_grad()


def test_short_fit_grows_where_the_error_is():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    n = 24  # a coarse grid of Gaussians covers the image
    xy = np.stack(np.meshgrid(np.linspace(-0.4, 0.4, 6), np.linspace(-0.4, 0.4, 4)), -1).reshape(-1, 2)
    g = _gs(np.c_[xy + rng.normal(0, 0.01, xy.shape), np.full(n, 2.0)], 0.04, opacity=0.5)
    opt = make_optimizer(g, {"means": 2e-3, "colors": 2e-2})
    cam = _cam()
    with torch.no_grad():  # the left half of the target is what the start renders already
        start = rasterize(g, cam)[0]
    xx = torch.arange(32)[None, :, None].expand(32, 32, 1)
    stripes = ((xx // 2) % 2).float() * torch.tensor([1.0, 0.0, 0.0])
    target = torch.where(xx >= 16, stripes, start)  # detail on the right only
    cfg = DensityConfig(grad_threshold=1e-3, percent_dense=0.1, refine_start=5, refine_every=5,
                        refine_stop=40, reset_every=0, max_gaussians=300)
    s = DensityStrategy(cfg, scene_extent=1.0)
    for step in range(1, 41):
        rgb, _, _, info = rasterize(g, cam, return_info=True)
        s.step_pre_backward(info)
        opt.zero_grad()
        ((rgb - target) ** 2).mean().backward()  # L2: no gradient where there is no error
        opt.step()
        s.step_post_backward(g, opt, info, step)
    assert len(g) > 3 * n
    u = 32 * g.means.detach()[:, 0] / g.means.detach()[:, 2] + 16
    assert (u >= 16).float().mean() > 0.75  # the new Gaussians went to the detailed half


def test_bad_config_and_state():
    with pytest.raises(GeofaceError, match="split_n"):
        DensityConfig(split_n=0)
    with pytest.raises(GeofaceError, match="scene_extent"):
        DensityStrategy(scene_extent=0)
    g = _gs([[0, 0, 2.0]], 0.01)
    m = torch.zeros(1, 2, requires_grad=True)
    with pytest.raises(GeofaceError, match="grad"):
        DensityStrategy().update_state(g, {"means2d": m, "radii": torch.ones(1), "width": 8, "height": 8})


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("backend", ["torch", "gsplat"])
def test_density_on_cuda(backend):
    if backend == "gsplat":
        pytest.importorskip("gsplat")
    torch.manual_seed(0)
    g, _ = _train_setup(40)
    g = g.cuda()
    opt = make_optimizer(g)
    cam = _cam()
    target = torch.zeros(32, 32, 3, device="cuda")
    s = DensityStrategy(DensityConfig(grad_threshold=1e-12, refine_start=0, refine_every=1,
                                      reset_every=2, percent_dense=0.02), scene_extent=1.0)
    for step in (1, 2, 3):
        rgb, _, _, info = rasterize(g, cam, backend=backend, return_info=True)
        s.step_pre_backward(info)
        opt.zero_grad()
        (rgb - target).abs().mean().backward()
        opt.step()
        out = s.step_post_backward(g, opt, info, step)
        assert out["n"] == len(g) and g.means.is_cuda and g.parent.is_cuda
        for grp in opt.param_groups:
            p = grp["params"][0]
            assert opt.state[p]["exp_avg"].shape == p.shape and opt.state[p]["exp_avg"].is_cuda
    assert len(g) > 40
