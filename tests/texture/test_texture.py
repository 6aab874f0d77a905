import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface.errors import CheckpointError, LearnError  # noqa: E402
from geoface.texture.model import (TextureModel, TextureTrainConfig, load_sample,  # noqa: E402
                                   reconstruct, save_sample, train_texture)
from geoface.texture.nets import TextureNetConfig  # noqa: E402

NETS = TextureNetConfig(predictor_widths=[8, 16], gde_widths=[8, 16], hfdr_widths=[8, 16],
                        hash_log2_table=10, hash_max_res=64)


def _make_data(root, n=4, H=64, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:H] / H
    for i in range(n):
        uv = np.stack([xx, yy], -1)
        nrm = np.stack([0.5 + 0.2 * (xx - 0.5), 0.5 + 0.2 * (yy - 0.5), np.full_like(xx, 0.95)], -1)
        tone = rng.uniform(0.3, 0.8, 3)
        fine = 0.1 * np.sin(2 * np.pi * 16 * xx) * np.sin(2 * np.pi * 16 * yy)
        albedo = np.clip(tone * (1 + fine[..., None]), 0, 1)
        micro = np.stack([0.5 + fine, 0.5 - fine, np.full_like(xx, 0.97)], -1)
        spec = (0.3 + 0.5 * yy)[..., None]
        photo = np.clip(albedo * (0.6 + 0.4 * nrm[..., 2:3]) + 0.2 * spec, 0, 1)
        mask = np.ones((H, H), bool)
        save_sample(root / f"s{i}.npz", photo, np.concatenate([albedo, micro, spec], -1), uv, nrm, mask)
    return root


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = _make_data(tmp_path_factory.mktemp("tex_data"))
    cfg = TextureTrainConfig(nets=NETS, gde_res=32, k=2, epochs=(6, 6, 6), lr=3e-3, batch=2, hfdr_patches=2)
    out = tmp_path_factory.mktemp("tex_model") / "model"
    info = train_texture(root, out, cfg, quiet=True)
    return root, out, info


def test_sample_round_trip(tmp_path):
    _make_data(tmp_path, n=1, H=32)
    d = load_sample(tmp_path / "s0.npz")
    assert d["photo"].shape == (32, 32, 3) and d["maps"].shape == (32, 32, 7) and d["mask"].all()
    # uint16 storage: UV error below 1e-5
    assert np.abs(d["uv"][0, :, 0] - np.arange(32) / 32).max() < 1e-5
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(LearnError):
        load_sample(tmp_path / "bad.npz")


def test_each_stage_lowers_its_loss(trained):
    _, _, info = trained
    for stage, h in info["history"].items():
        assert len(h) == 6
        assert h[-1] < h[0], (stage, h)


def test_reconstruct_shapes_save_load_and_baseline(trained):
    root, out, _ = trained
    m = TextureModel.load(out)
    photo = load_sample(root / "s0.npz")["photo"]
    r = reconstruct(m, photo)
    assert r["albedo"].shape == (64, 64, 3) and r["specular"].shape == (64, 64, 1)
    assert r["uv"].shape == (64, 64, 2) and np.isfinite(r["albedo"]).all()
    r2 = reconstruct(TextureModel.load(out), photo)
    np.testing.assert_array_equal(r["albedo"], r2["albedo"])
    base = reconstruct(m, photo, refine=False)
    assert base["albedo"].shape == (64, 64, 3) and not np.array_equal(base["albedo"], r["albedo"])
    with pytest.raises(LearnError, match="square RGB"):
        reconstruct(m, photo[:, :32])
    with pytest.raises(LearnError):
        reconstruct(m, np.zeros((66, 66, 3), np.float32))
    bad = photo.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(LearnError, match="NaN"):
        reconstruct(m, bad)


def test_corrupt_model_dir(trained, tmp_path):
    _, out, _ = trained
    import shutil
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    data = (broken / "model.safetensors").read_bytes()
    (broken / "model.safetensors").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError):
        TextureModel.load(broken)
    with pytest.raises(CheckpointError):
        TextureModel.load(tmp_path / "nothing")


def test_bad_data_dir(tmp_path):
    with pytest.raises(LearnError, match="no \\*.npz"):
        train_texture(tmp_path, tmp_path / "m", TextureTrainConfig(nets=NETS))


def test_training_streams_its_samples(tmp_path):
    """Training holds one full-resolution sample at a time (plus the gde_res copies): the numpy
    memory peak while training on 8 samples stays under three samples' float32 arrays (holding
    them all, as training once did, peaks above eight)."""
    import tracemalloc
    (tmp_path / "d").mkdir()
    root = _make_data(tmp_path / "d", n=8, H=128)
    one = 128 * 128 * (3 + 7 + 2 + 3) * 4
    cfg = TextureTrainConfig(nets=NETS, gde_res=32, k=2, epochs=(1, 1, 2), batch=4, hfdr_patches=2)
    train_texture(root, tmp_path / "warm", cfg, quiet=True)  # first-call caches (imports, linecache) are not data
    tracemalloc.start()
    try:
        train_texture(root, tmp_path / "m", cfg, quiet=True)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 3 * one, (peak, one)


def test_crops_match_the_full_sample(tmp_path):
    _make_data(tmp_path, n=1, H=32)
    full = load_sample(tmp_path / "s0.npz")
    boxes = [(slice(0, 16), slice(16, 32)), (slice(8, 24), slice(0, 16))]
    crops = load_sample(tmp_path / "s0.npz", ("maps",), box=boxes)
    assert set(crops) == {"maps", "mask"}
    for (ys, xs), c, m in zip(boxes, crops["maps"], crops["mask"]):
        np.testing.assert_array_equal(c, full["maps"][ys, xs])
        np.testing.assert_array_equal(m, full["mask"][ys, xs])


def test_init_trains_only_the_stages_asked_for(trained, tmp_path):
    """``init`` starts from a trained model: epochs (0, 0, 2) keep its predictor and GDE exactly
    and move its HFDR; weights for the maps are checked; networks of other sizes are refused."""
    root, out, _ = trained
    src = TextureModel.load(out)
    cfg = TextureTrainConfig(**{**src.cfg.__dict__, "epochs": (0, 0, 2), "map_weights": (1.0, 4.0, 1.0)})
    train_texture(root, tmp_path / "m", cfg, quiet=True, init=out)
    new = TextureModel.load(tmp_path / "m")
    assert tuple(new.cfg.map_weights) == (1.0, 4.0, 1.0)
    a, b = src.state_dict(), new.state_dict()
    for k in a:
        if not k.startswith("hfdr."):
            assert torch.equal(a[k], b[k]), k
    assert any(not torch.equal(a[k], b[k]) for k in a if k.startswith("hfdr."))
    from geoface.errors import GeofaceError

    with pytest.raises(GeofaceError, match="map_weights"):  # refused when the config is made
        train_texture(root, tmp_path / "x", TextureTrainConfig(**{**cfg.__dict__, "map_weights": (1, -1, 1)}), quiet=True)
    with pytest.raises(GeofaceError, match="hfdr_map_weights"):
        train_texture(root, tmp_path / "x", TextureTrainConfig(**{**cfg.__dict__, "hfdr_map_weights": (1, 1)}), quiet=True)


def test_hfdr_map_weights_weigh_the_refiner_s_maps(trained, tmp_path):
    """The HFDR starts at its guidance and learns a map only through that map's loss weight: with
    albedo weighted 0 its albedo stays the GDE's, exactly, while the other maps move."""
    from geoface.texture.model import reconstruct

    root, out, _ = trained
    src = TextureModel.load(out)
    cfg = TextureTrainConfig(**{**src.cfg.__dict__, "epochs": (0, 0, 2), "hfdr_map_weights": (0.0, 1.0, 1.0)})
    m = TextureModel(cfg)
    m.load_state_dict({**m.state_dict(), **{k: v for k, v in src.state_dict().items() if not k.startswith("hfdr.")}})
    m.save(tmp_path / "init")
    train_texture(root, tmp_path / "m", cfg, quiet=True, init=tmp_path / "init")
    new = TextureModel.load(tmp_path / "m")
    assert tuple(new.cfg.hfdr_map_weights) == (0.0, 1.0, 1.0)
    from pathlib import Path

    photo = load_sample(sorted(Path(root).glob("*.npz"))[0])["photo"]
    a, b = reconstruct(new, photo, refine=True, smooth=False), reconstruct(new, photo, refine=False)
    np.testing.assert_allclose(a["albedo"], b["albedo"], atol=1e-6)
    assert np.abs(a["specular"] - b["specular"]).max() > 1e-4
    other = TextureTrainConfig(**{**cfg.__dict__, "nets": TextureNetConfig(**{**NETS.to_dict(), "use_hash": False})})
    with pytest.raises(LearnError, match="differ"):
        train_texture(root, tmp_path / "y", other, quiet=True, init=out)


def test_relative_tone_model_trains_saves_and_loads(tmp_path):
    """A model with gde_tone="relative" trains (its GDE loss falls), keeps the option and its
    tone weights through save/load, and an absolute model's weights are refused as its init."""
    (tmp_path / "d").mkdir()
    root = _make_data(tmp_path / "d")
    nets = TextureNetConfig(**{**NETS.to_dict(), "gde_tone": "relative"})
    cfg = TextureTrainConfig(nets=nets, gde_res=32, k=2, epochs=(2, 8, 1), lr=3e-3, batch=2, hfdr_patches=1)
    info = train_texture(root, tmp_path / "m", cfg, quiet=True)
    assert info["history"]["gde"][-1] < info["history"]["gde"][0]
    m = TextureModel.load(tmp_path / "m")
    assert m.cfg.nets.gde_tone == "relative" and hasattr(m.gde, "tone_weight")
    photo = load_sample(root / "s0.npz")["photo"]
    np.testing.assert_array_equal(reconstruct(m, photo)["albedo"], reconstruct(TextureModel.load(tmp_path / "m"), photo)["albedo"])
    absolute = TextureTrainConfig(**{**cfg.__dict__, "nets": NETS, "epochs": (0, 0, 1)})
    with pytest.raises(LearnError, match="differ"):
        train_texture(root, tmp_path / "m2", absolute, quiet=True, init=tmp_path / "m")
