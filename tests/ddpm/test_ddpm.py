import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("diffusers")
pytest.importorskip("accelerate")

from geoface import GeofaceError
from geoface.ddpm.model import (DDPMConfig, build_unet, ddpm_loss, load_run, sample,
                                to_geometry_images, train)
from geoface.errors import CheckpointError


def tiny(**kw):
    d = dict(res=8, block_out_channels=(8, 16), layers_per_block=1, attention_head_dim=4,
             norm_num_groups=4, text_encoder="hash:8", text_max_length=4, cross_attention_dim=8,
             num_train_timesteps=50, lr=3e-3, ema_decay=0.9, batch_size=4, steps=4,
             checkpoint_every=2, augment=True, seed=0)
    d.update(kw)
    return DDPMConfig(**d)


def test_shapes_and_config_roundtrip(tmp_path):
    torch.manual_seed(0)
    cfg = tiny()
    unet = build_unet(cfg)
    x = torch.randn(2, 9, 8, 8)
    out = unet(x, torch.tensor([3, 7]), encoder_hidden_states=torch.randn(2, 4, 8)).sample
    assert out.shape == x.shape
    cfg.save(tmp_path / "config.json")
    assert DDPMConfig.load(tmp_path / "config.json") == cfg


def test_few_steps_lower_loss_on_fixed_batch():
    torch.manual_seed(0)
    cfg = tiny()
    unet = build_unet(cfg)
    opt = torch.optim.AdamW(unet.parameters(), lr=3e-3)
    g = torch.Generator().manual_seed(1)
    x, eps = torch.randn(4, 9, 8, 8, generator=g), torch.randn(4, 9, 8, 8, generator=g)
    t, cond = torch.tensor([5, 10, 20, 40]), torch.randn(4, 4, 8, generator=g)
    losses = []
    for _ in range(15):
        loss, parts = ddpm_loss(unet(x + eps, t, encoder_hidden_states=cond).sample, eps)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert set(parts) == {"position", "normal", "texture"}
    assert losses[-1] < 0.8 * losses[0]


def test_train_save_load_sample_deterministic(gimage_dataset, tmp_path):
    run = tmp_path / "run"
    last = train(gimage_dataset, run, tiny(), quiet=True)
    assert last["step"] == 4
    for f in ("config.json", "model.safetensors", "ema.safetensors", "optimizer.safetensors", "state.json",
              "data_stats.safetensors"):
        assert (run / "checkpoint" / f).is_file()
    r1, r2 = load_run(run), load_run(run)
    st = r1.stats
    lo = torch.from_numpy(st.mean - st.bound * st.std[:, None, None])
    hi = torch.from_numpy(st.mean + st.bound * st.std[:, None, None])
    x = torch.randn(1, 9, 8, 8)
    c = r1.text.encode(["a smiling female"])
    torch.testing.assert_close(r1.unet(x, 3, encoder_hidden_states=c).sample,
                               r2.unet(x, 3, encoder_hidden_states=c).sample, rtol=0, atol=0)
    for sch in ("ddpm", "ddim"):
        a = sample(r1, "a smiling female", n=2, steps=3, scheduler=sch, guidance=2.0, seed=7, quiet=True)
        b = sample(r2, "a smiling female", n=2, steps=3, scheduler=sch, guidance=2.0, seed=7, quiet=True)
        assert a.shape == (2, 9, 8, 8)
        torch.testing.assert_close(a, b, rtol=0, atol=0)
        # x0 is clipped to the data range by default (standardised: mean ± bound·std), and the
        # last step lands on the clipped estimate
        assert bool(((a >= lo - 1e-5) & (a <= hi + 1e-5)).all())
        u = sample(r1, "a smiling female", n=2, steps=3, scheduler=sch, guidance=2.0, seed=7, quiet=True,
                   clip=None)
        assert u.shape == a.shape and torch.isfinite(u).all()
    c8 = sample(r1, "a smiling female", n=2, steps=3, seed=8, quiet=True)
    assert not torch.equal(a, c8)
    gis = to_geometry_images(a, r1.state)
    assert gis[0].image.shape == (9, 8, 8) and 0 <= gis[0].image.min() and gis[0].image.max() <= 1
    # resume continues to the new total
    last = train(gimage_dataset, run, tiny(steps=6), resume=True, quiet=True)
    assert last["step"] == 6 and load_run(run).state["step"] == 6


def test_corrupt_checkpoint_errors(gimage_dataset, tmp_path):
    run = tmp_path / "run"
    train(gimage_dataset, run, tiny(steps=2), quiet=True)
    ck = run / "checkpoint"
    # a config whose text encoder is not the one the weights were trained with (hash:16 over
    # hash:8): refused at loading, not a shape error at sampling
    cfg = json.loads((ck / "config.json").read_text())
    (ck / "config.json").write_text(json.dumps(dict(cfg, text_encoder="hash:16")))
    with pytest.raises(CheckpointError, match="16-dimensional"):
        load_run(run)
    (ck / "config.json").write_text(json.dumps(cfg))
    data = (ck / "ema.safetensors").read_bytes()
    (ck / "ema.safetensors").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_run(run)
    (ck / "config.json").unlink()
    with pytest.raises(GeofaceError, match="missing config.json"):
        load_run(run)
    with pytest.raises(GeofaceError, match="no checkpoint"):
        load_run(tmp_path / "nothing")


def test_attention_levels_and_old_configs(tmp_path):
    import json
    cfg = tiny(block_out_channels=(8, 16, 16), attention_levels=(1, 2))
    unet = build_unet(cfg)
    assert unet.config.down_block_types == ("DownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D")
    assert unet.config.up_block_types == ("CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "UpBlock2D")
    cfg.save(tmp_path / "config.json")
    assert DDPMConfig.load(tmp_path / "config.json") == cfg
    # a config written before the field existed keeps the original layout
    d = json.loads(tiny().to_json())
    d.pop("attention_levels")
    old = DDPMConfig.from_dict(d)
    assert old.attention_levels is None
    assert build_unet(old).config.down_block_types == ("CrossAttnDownBlock2D", "DownBlock2D")
    with pytest.raises(GeofaceError, match="attention_levels"):
        build_unet(tiny(attention_levels=(5,)))


def test_time_budget_stops_and_saves(gimage_dataset, tmp_path):
    last = train(gimage_dataset, tmp_path / "run", tiny(steps=100), quiet=True, max_seconds=0.0)
    assert last["step"] == 1 and load_run(tmp_path / "run").state["step"] == 1


def test_standardisation_roundtrip_and_old_runs(gimage_dataset, tmp_path):
    """A run stores its data statistics and samples through them; deleting the file is an
    error; a config from before standardisation loads unstandardised."""
    import json

    from geoface.ddpm.data import DataStats, GImageDataset, data_stats
    ds = GImageDataset(gimage_dataset, res=8)
    st = data_stats(ds)
    X = torch.stack([ds[i]["image"] for i in range(len(ds))])
    Z = st.forward(X)
    # each modality of the residual has unit spread and the mean image is the mean
    assert Z.mean(0).abs().max() < 1e-4
    for k in range(3):
        assert abs(float(Z[:, 3 * k:3 * k + 3].pow(2).mean()) - 1.0) < 1e-3
    assert float(Z.abs().max()) == pytest.approx(st.bound, rel=1e-5)
    torch.testing.assert_close(st.inverse(Z), X, rtol=0, atol=1e-6)
    st.save(tmp_path / "s.safetensors")
    back = DataStats.load(tmp_path / "s.safetensors")
    assert (back.mean == st.mean).all() and (back.std == st.std).all() and back.bound == pytest.approx(st.bound)
    with pytest.raises(GeofaceError, match="shape"):
        st.forward(torch.zeros(1, 9, 4, 4))

    run = tmp_path / "run"
    train(gimage_dataset, run, tiny(steps=2), quiet=True)
    (run / "checkpoint" / "data_stats.safetensors").unlink()
    with pytest.raises(CheckpointError, match="data_stats.safetensors"):
        load_run(run)
    d = json.loads((run / "checkpoint" / "config.json").read_text())
    d.pop("standardize")
    (run / "checkpoint" / "config.json").write_text(json.dumps(d))
    old = load_run(run)
    assert old.config.standardize is False and old.stats is None
    assert sample(old, "a head", n=1, steps=2, quiet=True).abs().max() <= 1 + 1e-5


def test_patched_unet_is_a_unet_over_pixel_blocks(gimage_dataset, tmp_path):
    """patch=2: a 16² image through an 8² UNet with 4x the channels; same call, same shape; an
    output pixel depends on its own block of the input (not just on a shuffled copy)."""
    torch.manual_seed(0)
    cfg = tiny(res=16, patch=2)
    unet = build_unet(cfg)
    assert unet.unet.config.sample_size == 8 and unet.unet.config.in_channels == 36
    x = torch.randn(2, 9, 16, 16, requires_grad=True)
    out = unet(x, torch.tensor([3, 7]), encoder_hidden_states=torch.randn(2, 4, 8)).sample
    assert out.shape == x.shape
    out[0, 0, 5, 5].backward()
    assert x.grad[0, :, 4:6, 4:6].abs().sum() > 0  # its own 2x2 block
    with pytest.raises(CheckpointError, match="patch"):
        tiny(res=16, patch=3)
    with pytest.raises(CheckpointError, match="prediction"):
        tiny(prediction="noise")
    # train, reload, sample: the patched model round-trips through a checkpoint
    run = tmp_path / "run"
    train(gimage_dataset, run, tiny(res=8, patch=2, prediction="v_prediction", schedule_shift=2.0), quiet=True)
    r = load_run(run)
    assert r.config.patch == 2 and r.config.prediction == "v_prediction" and r.config.schedule_shift == 2.0
    x1 = sample(r, "a head", n=2, steps=3, seed=1, quiet=True)
    x2 = sample(load_run(run), "a head", n=2, steps=3, seed=1, quiet=True)
    assert x1.shape == (2, r.config.channels, 8, 8) and torch.equal(x1, x2)


def test_shifted_schedule_lowers_log_snr_by_2_log_shift():
    import math

    import numpy as np

    from geoface.ddpm.model import build_scheduler, shifted_cosine_betas
    base = build_scheduler(tiny(num_train_timesteps=1000)).alphas_cumprod.double().numpy()
    s1 = np.cumprod(1 - np.asarray(shifted_cosine_betas(1000, 1.0)))
    assert np.allclose(s1, base, rtol=1e-5, atol=1e-9)  # shift 1 = diffusers' squaredcos_cap_v2
    s2 = build_scheduler(tiny(num_train_timesteps=1000, schedule_shift=2.0)).alphas_cumprod.double().numpy()
    logit = lambda a: np.log(a / (1 - a))  # noqa: E731
    k = slice(1, 900)  # away from the capped end
    assert np.allclose(logit(s2[k]) - logit(base[k]), -2 * math.log(2.0), atol=2e-3)


def test_prediction_targets():
    from geoface.ddpm.model import build_scheduler, ddpm_target
    g = torch.Generator().manual_seed(0)
    x0, eps = torch.randn(3, 9, 8, 8, generator=g), torch.randn(3, 9, 8, 8, generator=g)
    t = torch.tensor([1, 20, 45])
    s = build_scheduler(tiny(prediction="v_prediction"))
    xt = s.add_noise(x0, eps, t)
    a = s.alphas_cumprod[t].sqrt()[:, None, None, None]
    b = (1 - s.alphas_cumprod[t]).sqrt()[:, None, None, None]
    v = ddpm_target(s, x0, eps, t, "v_prediction")
    assert torch.allclose(v, a * eps - b * x0, atol=1e-6)
    assert torch.allclose(a * xt - b * v, x0, atol=1e-5)  # x0 recovered from v
    assert ddpm_target(s, x0, eps, t, "sample") is x0 and ddpm_target(s, x0, eps, t, "epsilon") is eps


def test_per_pixel_standardisation_and_support(gimage_dataset, tmp_path):
    """Per-pixel spreads: every pixel of every modality has unit spread over the items (where the
    floor does not act); the support is the pixels all items cover and survives a save."""
    from geoface.ddpm.data import DataStats, GImageDataset, data_stats
    ds = GImageDataset(gimage_dataset, res=8)
    X = torch.stack([ds[i]["image"] for i in range(len(ds))])
    M = torch.stack([ds[i]["mask"] for i in range(len(ds))])[:, 0] > 0.5
    st = data_stats(ds, per_pixel=True, floor=0.0)
    assert st.std.shape == st.mean.shape
    Z = st.forward(X)
    spread = Z.pow(2).reshape(len(X), 3, 3, 8, 8).mean(dim=(0, 2))  # per modality and pixel
    varies = torch.from_numpy(st.std[::3] > DataStats.MIN_STD * 10)
    assert torch.allclose(spread[varies], torch.ones_like(spread[varies]), atol=1e-3)
    torch.testing.assert_close(st.inverse(Z), X, rtol=0, atol=1e-5)
    assert float(Z.abs().max()) == pytest.approx(st.bound, rel=1e-5)
    assert (st.support == M.all(0).numpy()).all()

    class Holed:  # item 1 misses pixel (2, 3): the support must too
        def __len__(self):
            return len(ds)

        def __getitem__(self, key):
            it = dict(ds[key])
            if (key[0] if isinstance(key, tuple) else key) == 1:
                it["mask"] = it["mask"].clone()
                it["mask"][0, 2, 3] = 0
            return it
    holed = data_stats(Holed()).support
    assert not holed[2, 3] and holed.sum() == st.support.sum() - 1
    floored = data_stats(ds, per_pixel=True, floor=0.5)
    glob = data_stats(ds)
    assert (floored.std >= 0.5 * glob.std[:, None, None] - 1e-7).all()
    st.save(tmp_path / "s.safetensors")
    back = DataStats.load(tmp_path / "s.safetensors")
    assert (back.std == st.std).all() and (back.support == st.support).all()


def test_cosine_learning_rate():
    from geoface.ddpm.model import learning_rate
    c = tiny(lr=1e-3, steps=101, lr_schedule="cosine")
    lrs = [learning_rate(c, s) for s in range(101)]
    assert lrs[0] == pytest.approx(1e-3) and lrs[-1] == pytest.approx(1e-4) and lrs[50] == pytest.approx(5.5e-4)
    assert all(a >= b for a, b in zip(lrs, lrs[1:]))
    assert learning_rate(tiny(lr=1e-3), 77) == 1e-3
    with pytest.raises(CheckpointError, match="lr_schedule"):
        tiny(lr_schedule="step")
