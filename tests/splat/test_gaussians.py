import numpy as np
import pytest
import torch

from geoface.errors import GeofaceError
from geoface.splat.gaussians import (Gaussians, covariance, eval_sh, quat_to_rotmat,
                                     rotmat_to_quat, SH_C0)
from geoface.splat.ply import load_ply, save_ply


def _grid(n=4, h=0.5):
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    V = np.stack([i.ravel() * h, j.ravel() * h, np.zeros(n * n)], 1)
    idx = (i * n + j)[:-1, :-1].ravel()
    F = np.concatenate([np.stack([idx, idx + n, idx + 1], 1), np.stack([idx + 1, idx + n, idx + n + 1], 1)])
    return V, F


def test_quat_roundtrip_and_covariance():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.sign(q[:, :1])
    R = quat_to_rotmat(torch.tensor(q)).numpy()
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1, atol=1e-12)
    np.testing.assert_allclose(rotmat_to_quat(R), q, atol=1e-12)
    ls = torch.tensor(rng.normal(size=(50, 3)))
    S = covariance(ls, torch.tensor(q)).numpy()
    ev = np.sort(np.linalg.eigvalsh(S), 1)
    np.testing.assert_allclose(ev, np.sort(np.exp(2 * ls.numpy()), 1), rtol=1e-10)


def test_sh_degree0_constant_and_degree1_linear():
    sh = torch.zeros(2, 4, 3, dtype=torch.float64)
    sh[:, 0] = 1.0
    d = torch.tensor([[0, 0, 1.0], [1.0, 0, 0]])
    np.testing.assert_allclose(eval_sh(sh[:, :1], d).numpy(), SH_C0)
    sh[:, 2] = 1.0  # z coefficient
    out = eval_sh(sh, d.double()).numpy()
    np.testing.assert_allclose(out[0], SH_C0 + 0.4886025119029199)
    np.testing.assert_allclose(out[1], SH_C0)
    # degree 3 runs and is finite
    assert torch.isfinite(eval_sh(torch.randn(2, 16, 3), d)).all()
    with pytest.raises(GeofaceError, match="1, 4, 9 or 16"):
        eval_sh(torch.zeros(2, 5, 3), d)


def test_from_mesh_thgs_init():
    V, F = _grid()
    g = Gaussians.from_mesh(V, F, dtype=torch.float64, normal_scale=0.1)
    assert len(g) == len(V)
    assert torch.equal(g.parent, torch.arange(len(V)))
    R = quat_to_rotmat(g.quats.detach()).numpy()
    # normal (+z for this CCW grid? compute) is the third axis
    fn = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])
    nrm = fn / np.linalg.norm(fn)
    np.testing.assert_allclose(R[:, :, 2], np.broadcast_to(nrm, (len(V), 3)), atol=1e-12)
    s = np.exp(g.log_scales.detach().numpy())
    # every face has area 0.125; corner vertex 0 touches 1 face, others more, all equal areas
    np.testing.assert_allclose(s[:, 0], np.sqrt(0.125 / np.pi), rtol=1e-12)
    np.testing.assert_allclose(s[:, 1], s[:, 0])
    np.testing.assert_allclose(s[:, 2], 0.1 * s[:, 0])
    assert np.all(np.argmin(s, 1) == 2)


def test_from_mesh_scale_uses_mean_adjacent_area():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -2, 0.0]])
    F = np.array([[0, 1, 2], [0, 3, 1]])  # areas 0.5 and 1.0
    g = Gaussians.from_mesh(V, F, dtype=torch.float64)
    s = np.exp(g.log_scales.detach().numpy()[:, 0])
    np.testing.assert_allclose(s, np.sqrt(np.array([0.75, 0.75, 0.5, 1.0]) / np.pi), rtol=1e-12)
    with pytest.raises(GeofaceError, match="out of range"):
        Gaussians.from_mesh(V, F + 10)


def test_from_points_knn_scale():
    P = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0.0]])
    g = Gaussians.from_points(P, k=1, dtype=torch.float64)
    np.testing.assert_allclose(np.exp(g.log_scales.detach().numpy()[:, 0]), [1, 1, 2])


@pytest.mark.parametrize("k", [1, 4, 16])
def test_ply_roundtrip_exact(tmp_path, k):
    rng = np.random.default_rng(k)
    n = 17
    f = lambda *s: torch.tensor(rng.normal(size=s), dtype=torch.float32)  # noqa: E731
    g = Gaussians(f(n, 3), f(n, 3), f(n, 4), f(n), f(n, k, 3))
    p = tmp_path / "g.ply"
    save_ply(g, p)
    h = load_ply(p)
    for name in ("means", "log_scales", "quats", "opacity_logits", "colors"):
        assert torch.equal(getattr(g, name), getattr(h, name)), name
    head = p.read_bytes()[:2000].split(b"end_header")[0].decode()
    assert "property float f_dc_0" in head and "property float rot_3" in head
    assert head.count("f_rest_") == 3 * (k - 1)


def test_ply_rejects_other_files(tmp_path):
    p = tmp_path / "x.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(GeofaceError, match="binary_little_endian"):
        load_ply(p)


def test_from_mesh_takes_a_loaded_meshs_colours():
    """RGB floats, RGBA floats (alpha dropped) and 0–255 integers give the same colours."""
    V, F = _grid()
    rgb = np.random.default_rng(0).integers(0, 256, (len(V), 3))
    want = Gaussians.from_mesh(V, F, colors=rgb / 255.0, dtype=torch.float64).colors
    rgba = np.concatenate([rgb / 255.0, np.full((len(V), 1), 0.3)], 1)
    for cols in (rgba, rgb.astype(np.uint8), np.concatenate([rgb, np.full((len(V), 1), 255)], 1)):
        assert torch.allclose(Gaussians.from_mesh(V, F, colors=cols, dtype=torch.float64).colors, want)
    with pytest.raises(GeofaceError, match="colors must have shape"):
        Gaussians.from_mesh(V, F, colors=rgb[:, :2])
