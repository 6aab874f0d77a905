import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface.errors import LearnError  # noqa: E402
from geoface.texture.patches import (assemble_patches, guidance_crop, patch_boxes, seam_masks,  # noqa: E402
                                   smooth_seams, split_patches, stream_patches)


def test_split_assemble_exact_and_patch_contents():
    img = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(0))
    p = split_patches(img, 4)
    assert p.shape == (2, 16, 3, 12, 16)
    for i, j, ys, xs in patch_boxes(48, 64, 4):
        assert torch.equal(p[:, i * 4 + j], img[:, :, ys, xs])
    assert torch.equal(assemble_patches(p, 4), img)  # bit-exact


def test_bad_sizes():
    with pytest.raises(LearnError, match="divisible"):
        split_patches(torch.zeros(1, 1, 30, 32), 4)
    with pytest.raises(LearnError):
        assemble_patches(torch.zeros(1, 9, 1, 4, 4), 4)


def test_guidance_crop_matches_full_upsample():
    g = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    full = torch.nn.functional.interpolate(g, size=(64, 64), mode="bilinear", align_corners=False)
    for _, _, ys, xs in patch_boxes(64, 64, 4):
        crop = guidance_crop(g, (64, 64), (ys, xs))
        torch.testing.assert_close(crop, full[:, :, ys, xs], rtol=1e-10, atol=1e-10)
    # non-integer ratio
    full = torch.nn.functional.interpolate(g, size=(48, 48), mode="bilinear", align_corners=False)
    for _, _, ys, xs in patch_boxes(48, 48, 3):
        torch.testing.assert_close(guidance_crop(g, (48, 48), (ys, xs)), full[:, :, ys, xs],
                                   rtol=1e-10, atol=1e-10)


def test_smoothing_changes_only_seam_bands_and_removes_the_step():
    k, P = 4, 32
    # a patchwise-constant image: steps exactly at the seams
    vals = torch.arange(k * k, dtype=torch.float32).reshape(1, 1, k, k)
    img = vals.repeat_interleave(P, 2).repeat_interleave(P, 3)
    img = img + 0.01 * torch.rand(img.shape, generator=torch.Generator().manual_seed(0))
    out = smooth_seams(img, k)
    hm, vm = seam_masks(k * P, k * P, k)
    band = hm | vm
    assert torch.equal(out[..., ~band], img[..., ~band])
    assert bool((out[..., band] != img[..., band]).any())
    # the jump across a vertical seam shrinks a lot
    jump_before = (img[0, 0, :, P] - img[0, 0, :, P - 1]).abs().mean()
    jump_after = (out[0, 0, :, P] - out[0, 0, :, P - 1]).abs().mean()
    assert float(jump_after) < 0.3 * float(jump_before)
    # band geometry: 8 px centred on each internal seam
    assert int(vm[0].sum()) == 8 * (k - 1) and bool(vm[0, P - 4:P + 4].all())


def test_smoothing_leaves_a_smooth_image_nearly_unchanged():
    y, x = torch.meshgrid(torch.linspace(0, 1, 64), torch.linspace(0, 1, 64), indexing="ij")
    img = (0.3 * x + 0.2 * y)[None, None]  # linear: a symmetric kernel reproduces it
    out = smooth_seams(img, 4)
    # exact away from the image border (replicate padding bends a ramp at the border)
    assert float((out - img)[..., 8:-8, 8:-8].abs().max()) < 1e-6
    assert float((out - img).abs().max()) < 2e-3


def test_stream_patches_writes_every_patch_once():
    calls = []

    def fn(i, j, ys, xs):
        calls.append((i, j))
        return np.full((2, 8, 8), i * 10 + j, np.float32)

    out = stream_patches(fn, (32, 32), 4, channels=2)
    assert len(calls) == 16 and out[1, 8, 24] == 13 and out[0, 31, 0] == 30
    with pytest.raises(LearnError, match="shape"):
        stream_patches(lambda *a: np.zeros((2, 4, 4)), (32, 32), 4, channels=2)


@pytest.mark.parametrize("k,P", [(4, 32), (3, 20), (8, 8)])
def test_inplace_strip_smoothing_equals_full_image_version(k, P):
    from geoface.texture.patches import smooth_seams_inplace
    img = torch.rand(1, 5, k * P, k * P, generator=torch.Generator().manual_seed(k), dtype=torch.float64)
    full = smooth_seams(img.float(), k)[0].numpy()
    arr = img[0].float().numpy().copy()
    out = smooth_seams_inplace(arr, k)
    assert out is arr
    np.testing.assert_allclose(arr, full, atol=1e-6)
