"""The DDPM's data path: one normalisation for the whole dataset, lazy items with a bounded
cache, a shard and a seed per process, progress that speaks outside a terminal."""
import io
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface import GeofaceError
from geoface.ddpm.data import GImageDataset, Normalization, ShardSampler


def _sphere_items(root, radii, N=16):
    """One item per radius: a sphere patch of that radius, each stored in its own box."""
    from geoface.gimage import GeometryImage, save_gimage

    u, v = np.meshgrid(np.linspace(0.1, 0.9, N), np.linspace(0.1, 0.9, N))
    rows = []
    for k, r in enumerate(radii):
        th, ph = np.pi * v, np.pi * u
        P = r * np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)]) + np.array([0, 0, 5.0])[:, None, None]
        lo, hi = P.reshape(3, -1).min(1), P.reshape(3, -1).max(1)
        Nrm = (P - np.array([0, 0, 5.0])[:, None, None]) / r
        img = np.concatenate([(P - lo[:, None, None]) / (hi - lo)[:, None, None], (Nrm + 1) / 2]).astype(np.float32)
        meta = {"bbox_min": lo.tolist(), "bbox_max": hi.tolist(), "channels": ["px", "py", "pz", "nx", "ny", "nz"],
                "resolution": N, "version": 2, "align_corners": True}
        save_gimage(root / f"s{k}" / "aug0", GeometryImage(img, np.ones((N, N), bool), meta))
        rows.append({"item": f"s{k}/aug0", "status": "ok", "prompt": f"radius {r}",
                     "bbox": {"min": lo.tolist(), "max": hi.tolist()}})
    (root / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root


def test_one_normalisation_keeps_sizes_and_proportions(tmp_path):
    data = _sphere_items(tmp_path, [1.0, 2.0, 4.0])
    ds = GImageDataset(data)
    assert ds.modalities == ("position", "normal") and ds.channels == 6
    nz = ds.normalization
    rows = [json.loads(line) for line in (data / "manifest.jsonl").read_text().splitlines()]
    lo = np.min([r["bbox"]["min"] for r in rows], 0)
    hi = np.max([r["bbox"]["max"] for r in rows], 0)
    # the union of the boxes: its centre, and its largest half-extent for every axis
    assert nz.scale == pytest.approx(1.05 * np.max(hi - lo) / 2, rel=1e-12) and np.allclose(nz.center, (lo + hi) / 2)
    assert nz.scale == pytest.approx(1.05 * 4.0 * np.cos(0.1 * np.pi), rel=1e-3)
    ext = []
    for i in range(3):
        x = ds[i]["image"].numpy()
        P = x[:3].reshape(3, -1)
        assert np.abs(P).max() <= 1 / 1.05 + 1e-4
        # decoded back to mesh units, the sphere has its own radius
        c = np.asarray(nz.center)[:, None] + nz.scale * P
        r = np.linalg.norm(c - np.array([0, 0, 5.0])[:, None], axis=0)
        assert np.allclose(r, [1.0, 2.0, 4.0][i], rtol=2e-3)
        ext.append(np.ptp(P, axis=1))
    # sizes survive: a head twice as large is twice as large after normalisation (a per-item
    # box would have made them all the same)
    assert ext[1] / ext[0] == pytest.approx([2, 2, 2], rel=2e-3) and ext[2] / ext[0] == pytest.approx([4, 4, 4], rel=2e-3)
    # the same from meta.json when the manifest has no boxes (older datasets)
    (data / "manifest.jsonl").write_text("".join(json.dumps({k: v for k, v in r.items() if k != "bbox"}) + "\n" for r in rows))
    assert GImageDataset(data).normalization == nz
    assert Normalization.from_dict(nz.to_dict()) == nz
    with pytest.raises(GeofaceError):
        Normalization.from_dict({"center": [0, 0], "scale": 1})


def test_items_are_lazy_and_the_cache_is_bounded(tmp_path, monkeypatch):
    data = _sphere_items(tmp_path, [1.0, 1.5, 2.0, 2.5, 3.0, 3.5])
    reads = []
    ds = GImageDataset(data, cache_mb=0)
    real = ds._decode
    monkeypatch.setattr(ds, "_decode", lambda i: reads.append(i) or real(i))
    assert reads == []  # nothing read at construction
    ds[2], ds[2]
    assert reads == [2, 2]  # no cache: read each time
    one = 6 * 16 * 16 * 2 + 16 * 16  # an item in the cache: float16 image + uint8 mask
    ds2 = GImageDataset(data, cache_mb=2.5 * one / 2**20)
    reads2 = []
    real2 = ds2._decode
    monkeypatch.setattr(ds2, "_decode", lambda i: reads2.append(i) or real2(i))
    a = ds2[0]["image"]
    for i in (1, 0, 2, 3):
        ds2[i]
    assert ds2._cache_bytes <= 2.5 * one and len(ds2._cache) == 2
    assert reads2 == [0, 1, 2, 3]  # 0 was cached when asked again; 1 was dropped first
    torch.testing.assert_close(ds2[0]["image"], a, rtol=0, atol=0)  # cached or not, the same values


def test_shards_are_disjoint_and_seeded_per_process():
    n, world = 103, 4
    seen = []
    for rank in range(world):
        s = ShardSampler(n, rank=rank, world=world, seed=7)
        it = iter(s)
        draws = [next(it) for _ in range(300)]
        idx = {i for i, _ in draws}
        assert all(i % world == rank for i in idx) and len(idx) > 20
        seen.append([i for i, _ in draws])
        again = iter(ShardSampler(n, rank=rank, world=world, seed=7))
        assert [next(again) for _ in range(300)] == draws  # reproducible
        assert len({d for _, d in draws}) == 300  # every draw has its own augmentation seed
    assert len({tuple(s[:50]) for s in seen}) == world
    other = iter(ShardSampler(n, rank=0, world=world, seed=8))
    assert [next(other)[0] for _ in range(300)] != seen[0]
    with pytest.raises(GeofaceError):
        ShardSampler(3, rank=3, world=4)  # no item for the fourth process
    with pytest.raises(GeofaceError):
        ShardSampler(10, rank=4, world=4)


def test_progress_speaks_outside_a_terminal(monkeypatch):
    from geoface import progress as P

    buf = io.StringIO()
    clock = iter([0.0, 0.0, 1.0, 2.0, 30.0, 31.0, 31.0, 31.0])
    monkeypatch.setattr("time.perf_counter", lambda: next(clock))
    bar = P.StepProgress(100, "ddpm train", quiet=False, stream=buf, every=10.0)
    bar.update(loss=0.5)  # t=1: the first line at once
    bar.update(loss=0.4)  # t=2: quiet (less than 10 s since)
    bar.update(loss=0.3)  # t=30: a line
    bar.close()
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3 and lines[0].startswith("ddpm train: step 1/100 (1%), 1 steps/s")
    assert " left" in lines[1] and "loss 0.3" in lines[1] and "3/100" in lines[1]
    assert "1:39 left" in lines[0]  # 99 steps at 1 step/s


def test_progress_with_a_time_budget_says_when_the_budget_ends(monkeypatch):
    """--max-minutes 5 against 10,000 steps: the time left is the budget's, not 9 hours."""
    from geoface import progress as P

    buf = io.StringIO()
    clock = iter([0.0, 0.0, 2.0, 2.0, 2.0])
    monkeypatch.setattr("time.perf_counter", lambda: next(clock))
    bar = P.StepProgress(10000, "ddpm train", quiet=False, stream=buf, budget=300.0)
    bar.update(loss=0.5)  # t=2: 1 step at 0.5 steps/s: 5.5 hours for the steps, 298 s of budget
    line = buf.getvalue().splitlines()[0]
    assert "4:58 left" in line and "(time budget)" in line and "about 150 of 10000" in line, line


def test_small_preset_is_the_documented_model():
    from geoface.ddpm.model import PRESETS, DDPMConfig, build_unet

    cfg = DDPMConfig.preset("small", cross_attention_dim=384)
    n = sum(p.numel() for p in build_unet(cfg).parameters())
    assert 5.85e6 < n < 5.95e6  # the 5.9 M parameters the README quotes
    assert set(PRESETS) == {"tiny", "small", "base"}
    from geoface.cli import build_parser

    args = build_parser().parse_args(["ddpm", "train", "d", "-o", "r"])
    assert args.model == "small"


def test_training_uses_the_dataset_frame_and_decodes_samples_in_it(tmp_path):
    pytest.importorskip("diffusers")
    from geoface.ddpm.model import DDPMConfig, load_run, to_geometry_images, train

    data = _sphere_items(tmp_path / "d", [1.0, 2.0, 4.0], N=8)
    cfg = DDPMConfig.preset("tiny", res=8, text_encoder="hash:8", text_max_length=4, num_train_timesteps=20, steps=3,
                            batch_size=2, checkpoint_every=2)
    last = train(data, tmp_path / "run", cfg, quiet=True)
    assert last["step"] == 3 and last["steps_per_second"] > 0
    run = load_run(tmp_path / "run")
    st = run.state
    assert st["modalities"] == ["position", "normal"] and run.config.channels == 6 and st["items"] == 3
    nz = Normalization.from_dict(st["normalization"])
    # a real item through the sample path decodes to its own radius in mesh units
    x = GImageDataset(data, res=8, normalization=nz)[2]["image"][None]
    gi = to_geometry_images(x, st)[0]
    P = gi.positions().reshape(-1, 3)
    assert np.allclose(np.linalg.norm(P - [0, 0, 5.0], axis=1), 4.0, rtol=5e-3)


def test_downsampled_normals_are_unit_where_the_surface_folds(tmp_path):
    """A tent (two planes meeting at a 140° fold): each 2×2 block straddling the ridge averages two
    normals 140° apart, whose mean is 0.34 long — below the |n| > 0.5 coverage rule.  Downsampled
    items keep unit normals pointing between the two, and every pixel stays covered."""
    from geoface.gimage import GeometryImage, save_gimage
    from geoface.ddpm.data import unit_normals

    N = 16
    x = (np.arange(N) + 0.5) / N
    X, Y = np.meshgrid(x, x)
    a = np.radians(70.0)
    c = 9 / N  # the ridge between pixels 8 and 9: the 2x2 block of pixels 8-9 straddles it
    Z = np.abs(X - c) / np.tan(np.pi / 2 - a)
    side = np.where(X < c, -1.0, 1.0)
    Nrm = np.stack([side * np.sin(a) * np.ones_like(X), np.zeros_like(X), np.cos(a) * np.ones_like(X)])
    P = np.stack([X, Y, Z])
    lo, hi = P.reshape(3, -1).min(1), P.reshape(3, -1).max(1)
    img = np.concatenate([(P - lo[:, None, None]) / (hi - lo)[:, None, None], (Nrm + 1) / 2]).astype(np.float32)
    meta = {"bbox_min": lo.tolist(), "bbox_max": hi.tolist(), "channels": ["px", "py", "pz", "nx", "ny", "nz"],
            "resolution": N, "version": 2, "align_corners": True}
    save_gimage(tmp_path / "tent" / "aug0", GeometryImage(img, np.ones((N, N), bool), meta))
    ds = GImageDataset(tmp_path, res=8, cache_mb=0)
    it = ds[0]
    n = it["image"][3:6].numpy()
    assert np.allclose(np.linalg.norm(n, axis=0), 1.0, atol=1e-5) and it["mask"].min() == 1
    assert np.allclose(n[:, :, 4].T, [0.0, 0.0, 1.0], atol=1e-4)  # the ridge block: straight up, unit
    assert np.allclose(n[0, :, 3], -np.sin(a), atol=1e-4) and np.allclose(n[0, :, 5], np.sin(a), atol=1e-4)
    # unit_normals itself, on 3-wide blocks: short means come back unit, between the two sides
    full = Nrm[:, :15, 1:16].astype(np.float32)  # columns 7-9 in one block: two left of the ridge, one right
    mean = full.reshape(3, 5, 3, 5, 3).mean(axis=(2, 4))
    assert np.linalg.norm(mean, axis=0).min() < 0.5
    u = unit_normals(mean, full, np.ones((5, 5), bool))
    assert np.allclose(np.linalg.norm(u, axis=0), 1.0, atol=1e-6)
    assert np.all(u[2] >= np.cos(a) - 1e-6)  # never further from +z than the planes themselves
    cancel = unit_normals(np.zeros((3, 1, 1), np.float32), full[:, :1, :1], np.ones((1, 1), bool))
    assert np.allclose(cancel[:, 0, 0], full[:, 0, 0])  # normals that cancel: the block's first pixel stands in
