import pytest

torch = pytest.importorskip("torch")

from geoface.errors import CheckpointError  # noqa: E402
from geoface.errors import LearnError  # noqa: E402
from geoface.texture.nets import (GAMMA, GDE, HFDR, NormalUVPredictor, TextureNetConfig,  # noqa: E402
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
    assert GDE(TextureNetConfig(**{**CFG.to_dict(), "hash_mode": "input"})).net.inc.net[0].in_channels == 16
    assert TextureNetConfig.from_dict(CFG.to_dict()) == CFG
    with pytest.raises(CheckpointError, match="unknown fields"):  # a typo or another model's key: refused
        TextureNetConfig.from_dict({**CFG.to_dict(), "unknown": 1})


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
    first = float(loss_fn().detach())
    for _ in range(40 if which == "hfdr" else 25):  # the HFDR starts at the guidance (a zero residual)
        loss = loss_fn()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss_fn().detach()) < 0.8 * first


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


def test_relative_tone_gde_scales_albedo_with_the_photo():
    """With gde_tone="relative", a photo whose linear light is c times another's (a darker skin
    under the same light, or a shorter exposure) has c times the tone, the same network input,
    and albedo logits shifted by exactly logit(c·μ) − logit(μ); micronormal and specular do not
    change.  The absolute GDE does not have this property."""
    rgb, uv, n, _ = _batch(B=2)
    rgb = rgb * 0.8
    c = 0.3
    dark = (rgb ** GAMMA * c) ** (1 / GAMMA)
    rel = GDE(TextureNetConfig(**{**CFG.to_dict(), "gde_tone": "relative"})).eval()
    torch.manual_seed(1)
    for p in rel.tone_weight.parameters():  # weights that depend on the features, not uniform
        torch.nn.init.normal_(p, std=1.0)
    with torch.no_grad():
        mu, mu_dark = rel.tone(rgb, uv, n), rel.tone(dark, uv, n)
        a, b = rel(rgb, uv, n), rel(dark, uv, n)
    assert mu.shape == (2, 3, 1, 1)
    torch.testing.assert_close(mu_dark, c * mu, rtol=1e-5, atol=1e-7)
    # the tone is a weighted mean of the photo's linear colour: inside its range, not its plain mean
    lin = rgb ** GAMMA
    assert bool((mu >= lin.amin((2, 3), keepdim=True)).all() and (mu <= lin.amax((2, 3), keepdim=True)).all())
    assert float((mu - lin.mean((2, 3), keepdim=True)).abs().max()) > 1e-3
    shift = torch.logit(b[:, :3]) - torch.logit(a[:, :3])
    torch.testing.assert_close(shift, (torch.logit(mu_dark) - torch.logit(mu)).expand_as(shift), rtol=0, atol=1e-4)
    torch.testing.assert_close(b[:, 3:], a[:, 3:], rtol=0, atol=1e-5)
    with torch.no_grad():
        absolute = GDE(CFG).eval()
        d = torch.logit(absolute(dark, uv, n)[:, :3]) - torch.logit(absolute(rgb, uv, n)[:, :3])
    assert float((d - (torch.logit(mu_dark) - torch.logit(mu))).abs().max()) > 0.05


def test_gde_tone_option():
    with pytest.raises(LearnError, match="gde_tone"):
        TextureNetConfig(gde_tone="log")
    # a model saved before the option existed reads absolute tone
    old = {k: v for k, v in CFG.to_dict().items() if k != "gde_tone"}
    assert TextureNetConfig.from_dict(old).gde_tone == "absolute"
    rel = GDE(TextureNetConfig(**{**CFG.to_dict(), "gde_tone": "relative"}))
    assert rel.net.inc.net[0].in_channels == GDE(CFG).net.inc.net[0].in_channels
    assert not hasattr(GDE(CFG), "tone_weight")


def test_logit_hash_mode_adds_a_per_uv_offset():
    """hash_mode="logit": the hash features do not enter the network; a linear map of them is
    added to its albedo and specular logits — the same offset at the same UV whatever the photo
    (so a photo's tone is read by the network alone), zero at initialisation."""
    rgb, uv, n, _ = _batch(B=2)
    other = torch.rand_like(rgb) * 0.3  # a different, darker photo at the same UVs
    net = GDE(TextureNetConfig(**{**CFG.to_dict(), "hash_mode": "logit"})).eval()
    assert net.net.inc.net[0].in_channels == 8 and net.hash_logit.in_channels == net.hash.out_dim
    with torch.no_grad():
        start = net(rgb, uv, n)
        net.hash_logit.weight.zero_()  # (already zero: the photo-only GDE at initialisation)
        torch.testing.assert_close(net(rgb, uv, n), start)
        torch.nn.init.normal_(net.hash.tables, std=0.5)
        torch.nn.init.normal_(net.hash_logit.weight, std=0.5)
        offset = {}
        for name, photo in (("a", rgb), ("b", other)):
            with_hash = net(photo, uv, n)
            w = net.hash_logit.weight.clone()
            net.hash_logit.weight.zero_()
            without = net(photo, uv, n)
            net.hash_logit.weight.copy_(w)
            idx = [0, 1, 2, 6]
            offset[name] = torch.logit(with_hash[:, idx]) - torch.logit(without[:, idx])
    assert float(offset["a"].abs().mean()) > 0.1
    torch.testing.assert_close(offset["a"], offset["b"], rtol=0, atol=1e-3)
    with pytest.raises(LearnError, match="hash_mode"):
        TextureNetConfig(hash_mode="both")
    old = {k: v for k, v in CFG.to_dict().items() if k != "hash_mode"}
    assert TextureNetConfig.from_dict(old).hash_mode == "input"
