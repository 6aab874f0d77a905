import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface.nn.losses import dssim, laplacian, laplacian_loss, ssim  # noqa: E402


def test_laplacian_loss_zero_for_identical_and_for_low_frequency_error():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 32, 32, generator=g)
    assert float(laplacian_loss(a, a)) == 0.0
    y, x = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
    ramp = (0.01 * x + 0.02 * y)[None, None]
    assert float(laplacian_loss(a + 0.5, a)) < 1e-6  # constant offset
    inner = laplacian(a + ramp)[..., 1:-1, 1:-1] - laplacian(a)[..., 1:-1, 1:-1]
    assert float(inner.abs().max()) < 1e-5  # linear error: zero away from the border


def test_laplacian_loss_penalises_high_frequency_error():
    a = torch.zeros(1, 1, 32, 32)
    y, x = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="ij")
    checker = 0.1 * (((x + y) % 2) * 2 - 1).float()[None, None]
    smooth = 0.1 * torch.sin(x / 32.0 * np.pi)[None, None].float()
    # same L1 magnitude order, very different Laplacian cost
    assert float(laplacian_loss(a + checker, a)) > 20 * float(laplacian_loss(a + smooth, a))
    assert float(laplacian_loss(a + checker, a)) == pytest.approx(0.8, rel=0.05)  # |Δ| = 8·0.1 inside


def test_ssim_properties_and_skimage_agreement():
    skm = pytest.importorskip("skimage.metrics")
    g = torch.Generator().manual_seed(3)
    a = torch.rand(1, 1, 40, 40, generator=g, dtype=torch.float64)
    b = (a + 0.1 * torch.randn(1, 1, 40, 40, generator=g, dtype=torch.float64)).clamp(0, 1)
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-12)
    assert float(ssim(a, b)) == pytest.approx(float(ssim(b, a)), abs=1e-12)
    ref = skm.structural_similarity(a[0, 0].numpy(), b[0, 0].numpy(), data_range=1.0,
                                    gaussian_weights=True, sigma=1.5, use_sample_covariance=False)
    # skimage averages over the image minus a (window-1)/2 border, as the valid convolution does
    assert float(ssim(a, b)) == pytest.approx(ref, abs=2e-3)
    assert float(dssim(a, a)) == pytest.approx(0.0, abs=1e-12)
    assert 0 < float(dssim(a, b)) < 0.5
