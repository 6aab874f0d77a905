import pytest

torch = pytest.importorskip("torch")

from geoface.learn.errors import LearnError  # noqa: E402
from geoface.learn.texture_nets import (GDE, HFDR, NormalUVPredictor, TextureNetConfig,  # noqa: E402
                                        UNet, map_loss, pack_maps)

CFG = TextureNetConfig(predictor_widths=[8, 16], gde_widths=[8, 16], hfdr_widths=[8, 16],
                       hash_log2_table=10, hash_max_res=64)


def _batch(seed=0, B=2, S=32):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(B, 3, S, S, generator=g)
    uv = torch.rand(B, 2, S, S, generator=g)
    n = torch.nn.functional.normalize(torch.randn(B, 3, S, S, generator=g), dim=1)
    # targets with structure the nets can pick up from the inputs
    target = torch.cat([rgb.flip(1), n * 0.5 + 0.5, uv[:, :1]], 1)
    return rgb, uv, n, target


def test_shapes_ranges_and_unit_normals():
    rgb, uv, n, _ = _batch()
    with torch.no_grad():
        puv, pn = NormalUVPredictor(CFG.predictor_widths)(rgb)
        maps = GDE(CFG)(rgb, uv, n)
        out = HFDR(CFG)(rgb, uv, n, maps)
    assert puv.shape == (2, 2, 32, 32) and pn.shape == (2, 3, 32, 32)
    assert float(puv.min()) >= 0 and float(puv.max()) <= 1
    torch.testing.assert_close(pn.norm(dim=1), torch.ones(2, 32, 32))
    assert maps.shape == (2, 7, 32, 32) and float(maps.min()) >= 0 and float(maps.max()) <= 1
    torch.testing.assert_close((maps[:, 3:6] * 2 - 1).norm(dim=1), torch.ones(2, 32, 32))
    assert out.shape == (2, 7, 32, 32)
    torch.testing.assert_close((out[:, 3:6] * 2 - 1).norm(dim=1), torch.ones(2, 32, 32))


def test_errors():
    with pytest.raises(LearnError, match="divisible"):
        UNet(3, 3, [4, 8, 16])(torch.zeros(1, 3, 30, 30))
    with pytest.raises(LearnError, match="guidance"):
        UNet(3, 3, [4, 8], late_channels=7)(torch.zeros(1, 3, 16, 16))


def test_pack_maps_zero_logits_is_flat_normal():
    m = pack_maps(torch.zeros(1, 7, 4, 4))
    torch.testing.assert_close(m[:, 3:6], torch.tensor([0.5, 0.5, 1.0])[None, :, None, None].expand(1, 3, 4, 4))


def test_hash_encoding_can_be_switched_off():
    off = GDE(TextureNetConfig(**{**CFG.to_dict(), "use_hash": False}))
    assert off.hash is None and off.net.inc.net[0].in_channels == 8
    assert GDE(CFG).net.inc.net[0].in_channels == 16
    assert TextureNetConfig.from_dict({**CFG.to_dict(), "unknown": 1}) == CFG


def test_hfdr_starts_as_the_guidance():
    """A fresh HFDR returns its guidance maps (albedo and specular exactly, micronormals
    renormalised), so training starts from the GDE's maps rather than from noise around them."""
    rgb, uv, n, target = _batch()
    guide = torch.nn.functional.avg_pool2d(target, 4)
    guide = torch.nn.functional.interpolate(guide, scale_factor=4, mode="bilinear")
    with torch.no_grad():
        out = HFDR(CFG)(rgb, uv, n, guide)
    assert torch.equal(out[:, [0, 1, 2, 6]], guide[:, [0, 1, 2, 6]].clamp(0, 1))
    want = torch.nn.functional.normalize(guide[:, 3:6] * 2 - 1, dim=1, eps=1e-6) * 0.5 + 0.5
    assert torch.allclose(out[:, 3:6], want, atol=1e-6)


@pytest.mark.parametrize("which", ["predictor", "gde", "hfdr"])
def test_a_few_steps_lower_each_loss(which):
    torch.manual_seed(0)
    rgb, uv, n, target = _batch()
    if which == "predictor":
        net = NormalUVPredictor(CFG.predictor_widths)

        def loss_fn():
            puv, pn = net(rgb)
            return (puv - uv).abs().mean() + (pn - n).abs().mean()
    elif which == "gde":
        net = GDE(CFG)

        def loss_fn():
            return map_loss(net(rgb, uv, n), target, 1.0)[0]
    else:
        net = HFDR(CFG)
        guide = torch.nn.functional.avg_pool2d(target, 4)
        guide = torch.nn.functional.interpolate(guide, scale_factor=4, mode="bilinear")

        def loss_fn():
            return map_loss(net(rgb, uv, n, guide), target, 2.0)[0]
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    first = float(loss_fn())
    for _ in range(40 if which == "hfdr" else 25):  # the HFDR starts at the guidance (a zero residual)
        loss = loss_fn()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss_fn()) < 0.8 * first


def test_map_loss_parts():
    _, _, _, t = _batch()
    loss, parts = map_loss(t, t)
    assert float(loss) == 0 and parts["albedo"] == 0 and set(parts) >= {"micronormal", "specular", "laplacian"}


def test_detail_band_hfdr_keeps_the_gde_texel_means():
    """With hfdr_band="detail" the refiner's change to albedo and specular averages to zero over
    every GDE texel the patch spans (it adds only what the GDE grid cannot hold); a "full" band
    refiner with the same weights shifts those means."""
    rgb, uv, n, target = _batch()
    guide = torch.full_like(target, 0.5)
    outs = {}
    for band in ("full", "detail"):
        torch.manual_seed(3)
        net = HFDR(TextureNetConfig(**{**CFG.to_dict(), "hfdr_band": band}))
        for p in net.parameters():  # away from the zero start, so the residual is not zero
            torch.nn.init.normal_(p, std=0.2)
        with torch.no_grad():
            outs[band] = net(rgb, uv, n, guide, grid=(8, 8))  # 32² patch over 8² texels
    for band, out in outs.items():
        means = torch.nn.functional.avg_pool2d(out - guide, 4)[:, [0, 1, 2, 6]]
        change = (out - guide)[:, [0, 1, 2, 6]].abs().mean()
        assert float(change) > 1e-3, band  # both refine
        if band == "detail":
            assert float(means.abs().max()) < 1e-6
        else:
            assert float(means.abs().max()) > 1e-3
    with pytest.raises(LearnError, match="grid"):
        HFDR(TextureNetConfig(**{**CFG.to_dict(), "hfdr_band": "detail"}))(rgb, uv, n, guide)
    with pytest.raises(LearnError, match="hfdr_band"):
        TextureNetConfig(hfdr_band="low")
    # a model saved before the option existed refines every band
    old = {k: v for k, v in CFG.to_dict().items() if k != "hfdr_band"}
    assert TextureNetConfig.from_dict(old).hfdr_band == "full"
