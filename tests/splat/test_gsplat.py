"""The CPU rasterizer against gsplat on CUDA (skipped without a GPU and gsplat).

Run on a GPU machine: ``pytest tests/splat/test_gsplat.py``.  The two differ by design only
at a Gaussian's 3σ edge (we cut each Gaussian per pixel at its 3σ box; gsplat evaluates every
Gaussian binned to a tile over the whole tile), so the comparison is on means and on the bulk
of the pixels, with a looser bound on the maximum.
"""
import numpy as np
import pytest

torch = pytest.importorskip("torch")
if not torch.cuda.is_available():
    pytest.skip("needs CUDA", allow_module_level=True)
pytest.importorskip("gsplat")

from geoface.splat import GaussianTensors, look_at, rasterize  # noqa: E402


def _scene(n, sh, seed=0, device="cuda"):
    g = np.random.default_rng(seed)
    means = g.normal(0, 0.25, (n, 3))
    log_scales = np.log(g.uniform(0.01, 0.05, (n, 3)))
    quats = g.normal(size=(n, 4))
    opac = g.normal(0, 1.5, n)
    colors = g.normal(0, 0.3, (n, 16, 3)) if sh else g.uniform(0, 1, (n, 3))
    t = lambda a: torch.tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    return GaussianTensors(t(means), t(log_scales), t(quats), t(opac), t(colors))


@pytest.mark.parametrize("sh", [False, True])
def test_torch_path_matches_gsplat_on_cuda(sh):
    cam = look_at((0.3, 0.2, 2.0), (0, 0, 0), width=96, height=80)
    gs = _scene(400, sh)
    ours = rasterize(gs, cam, background=(0.1, 0.2, 0.3), backend="torch")
    ref = rasterize(gs, cam, background=(0.1, 0.2, 0.3), backend="gsplat")
    for name, a, b in zip(("rgb", "alpha"), ours[:2], ref[:2]):
        assert a.shape == b.shape, name
        d = (a - b).abs()
        assert float(d.mean()) < 2e-3, (name, float(d.mean()))
        assert float(torch.quantile(d.flatten(), 0.99)) < 2e-2, name
    m = (ours[1] > 0.5) & (ref[1] > 0.5)
    rel = ((ours[2] - ref[2]).abs() / ref[2].clamp_min(1e-6))[m]
    assert float(rel.median()) < 1e-3


def test_gradients_agree_in_direction():
    cam = look_at((0.0, 0.0, 2.0), (0, 0, 0), width=64, height=64)
    grads = []
    for backend in ("torch", "gsplat"):
        gs = _scene(200, False, seed=3)
        gs.means.requires_grad_(True)
        gs.colors.requires_grad_(True)
        rgb, _, _ = rasterize(gs, cam, backend=backend)
        (rgb * torch.linspace(0, 1, 3, device="cuda")).sum().backward()
        grads.append(torch.cat([gs.means.grad.flatten(), gs.colors.grad.flatten()]))
    cos = torch.nn.functional.cosine_similarity(grads[0], grads[1], dim=0)
    assert float(cos) > 0.98
