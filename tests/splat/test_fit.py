import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface.nn.losses import dssim, ssim  # noqa: E402  (the D-SSIM term of the fit loss)
from geoface.splat.fit import FitConfig, fit_cameras, fit_mesh, psnr  # noqa: E402


def _coloured_sphere(subdiv=3):
    from geoface.synth import sphere

    V, F = sphere(0.5, subdiv)
    C = np.column_stack([0.5 + 0.5 * V[:, 0] / 0.5, 0.5 + 0.4 * np.sin(6 * V[:, 1]), 0.3 + 0.6 * (V[:, 2] > 0)])
    return V, F, np.clip(C, 0, 1)


def test_ssim_identity_symmetry_and_skimage():
    skm = pytest.importorskip("skimage.metrics")
    g = torch.Generator().manual_seed(0)
    a = torch.rand(1, 3, 40, 36, generator=g, dtype=torch.float64)
    b = (a + 0.2 * torch.rand(1, 3, 40, 36, generator=g, dtype=torch.float64)).clamp(0, 1)
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-12)
    assert float(ssim(a, b)) == pytest.approx(float(ssim(b, a)), abs=1e-12)
    assert float(dssim(a, a)) == pytest.approx(0.0, abs=1e-12)
    ref = skm.structural_similarity(a[0].permute(1, 2, 0).numpy(), b[0].permute(1, 2, 0).numpy(),
                                    channel_axis=2, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)
    assert float(ssim(a, b)) == pytest.approx(ref, abs=1e-3)


def test_psnr():
    a = torch.zeros(4, 4, 3)
    assert psnr(a, a + 0.1) == pytest.approx(20.0)
    assert psnr(a, a) == float("inf")
    m = torch.zeros(4, 4, dtype=torch.bool)
    m[0, 0] = True
    b = a.clone()
    b[1:] = 0.5
    assert psnr(a, b, m) == float("inf")


def test_heldout_cameras_differ_from_training_ones():
    V, _, _ = _coloured_sphere(1)
    train, held, extent = fit_cameras(V, FitConfig(views=12, heldout=4, res=32))
    assert len(train) == 12 and len(held) == 4 and extent > 0
    ct = np.array([c.center for c in train])
    for c in held:
        d = np.linalg.norm(ct - c.center, axis=1).min()
        assert d > 0.05 * np.linalg.norm(c.center)
    # elevations differ too: no held-out camera height equals a training height
    assert not set(np.round([c.center[1] for c in held], 6)) & set(np.round(ct[:, 1], 6))


def test_fit_raises_psnr_on_a_short_run():
    V, F, C = _coloured_sphere(2)
    base = dict(views=6, heldout=2, res=32, seed=0, threads=1, elevations=(-20.0, 25.0))
    r0 = fit_mesh(V, F, C, FitConfig(iters=0, **base), progress=False)
    r1 = fit_mesh(V, F, C, FitConfig(iters=150, densify=False, **base), progress=False)
    assert r1.psnr_train > r0.psnr_train + 5
    assert r1.psnr_heldout > r0.psnr_heldout + 5
    assert r1.iterations == 150 and r1.n_gaussians == len(V) and len(r1.history) == 150
    assert r1.history[-1]["loss"] < r1.history[0]["loss"]


def test_fit_rejects_missing_colours():
    from geoface import GeofaceError

    V, F, _ = _coloured_sphere(1)
    with pytest.raises(GeofaceError, match="colors"):
        fit_mesh(V, F, None, FitConfig(iters=1, res=16))
    with pytest.raises(GeofaceError, match="background"):
        FitConfig(background="grey")


def test_cli_end_to_end(tmp_path, capsys):
    from geoface.cli import main
    from geoface.mesh.io import save_mesh
    from geoface.splat.ply import load_ply

    V, F, C = _coloured_sphere(2)
    mesh = tmp_path / "ball.ply"
    save_mesh(mesh, V=V, F=F, colors=C)
    out, renders = tmp_path / "fit" / "ball_gs.ply", tmp_path / "renders"
    rc = main(["splat", "fit", str(mesh), "-o", str(out), "--views", "4", "--res", "24", "--iters", "10",
               "--heldout", "2", "--seed", "1", "--threads", "1", "--renders", str(renders), "-q"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "PSNR train" in text and "held-out" in text
    g = load_ply(out)
    assert len(g) == len(V)
    assert sorted(p.name for p in renders.iterdir()) == ["heldout_00.png", "heldout_01.png"]
    assert not [p for p in out.parent.iterdir() if p.name != out.name]  # no temporary left


def test_cli_errors_are_one_line_exit_2(tmp_path, capsys):
    from geoface.cli import main
    from geoface.mesh.io import save_mesh

    V, F, _ = _coloured_sphere(1)
    plain = tmp_path / "plain.ply"
    save_mesh(plain, V=V, F=F)
    broken = tmp_path / "broken.ply"
    broken.write_bytes(b"ply\nformat nonsense\n")
    for src in (tmp_path / "missing.ply", broken, plain):
        rc = main(["splat", "fit", str(src), "-o", str(tmp_path / "o.ply"), "--iters", "1", "-q"])
        err = capsys.readouterr().err
        assert rc == 2
        assert err.startswith("geoface: error:") and err.count("\n") == 1
    assert not (tmp_path / "o.ply").exists()


def test_fit_with_density_control_and_sh():
    V, F, C = _coloured_sphere(2)
    cfg = FitConfig(views=4, heldout=1, res=32, iters=90, seed=0, threads=1, sh_degree=1,
                    density={"refine_start": 20, "refine_stop": 80, "refine_every": 30, "grad_threshold": 1e-6})
    r = fit_mesh(V, F, C, cfg, progress=False)
    grown = [h for h in r.history if h.get("cloned") or h.get("split")]
    assert grown and r.n_gaussians > len(V)
    assert len(r.gaussians.parent) == r.n_gaussians  # parent index kept through densification
    assert r.gaussians.colors.shape[1:] == (4, 3)
    assert float(r.gaussians.colors.detach()[:, 1:].abs().max()) > 0  # view-dependent terms trained
