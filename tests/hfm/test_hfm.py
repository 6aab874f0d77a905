"""HFM-GS: mapping weights, key sampling, W_dist, segregation, identity at init, training, I/O."""
from __future__ import annotations

import importlib.util
import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy import ndimage

from geoface.splat.density import DensityConfig
from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians
from geoface.hfm import (ABLATIONS, HFMConfig, HFMModel, SegregationStrategy, VGGPerceptual, WeightAverage, select_keys,
                               boundary_loss, evaluate_hmd, farthest_point_sampling, hmd_metrics,
                               inverse_distance_weights, load_hfm, save_hfm, train_hfm)
from geoface.hfm.data import (LOWER_FACE_LANDMARKS, UPPER_EXPRESSIONS, HMDVideo, crop_lower_face,
                                    load_video, lower_face_box, make_synthetic_hmd)

Y_T = 0.0


def _model(n=3000, seed=0, **cfg):
    """Gaussians on a unit-ish sphere around the origin, split at y = 0."""
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g)
    X = 0.1 * d / d.norm(dim=1, keepdim=True)
    gs = Gaussians(X, torch.full((n, 3), math.log(0.005)), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                   torch.zeros(n), torch.rand(n, 3, generator=g))
    return HFMModel(gs, HFMConfig(**cfg), Y_T)


def _perturb(model, std=0.05, seed=1):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if not name.startswith("gaussians."):
                p.add_(torch.randn(p.shape, generator=g) * std)


def test_w_gm_rows_sum_to_one():
    m = _model(400)
    _perturb(m)
    E = m.embed(m.gaussians.means.detach())
    up = m.upper_mask()
    W = m.w_gm(E[up], E[~up])
    assert W.shape == (int(up.sum()), int((~up).sum()))
    assert torch.all(W >= 0)
    assert torch.allclose(W.sum(1), torch.ones(len(W)), atol=1e-6)


def test_sampling_keeps_exactly_512_plus_512_keys_by_correlation():
    m = _model(3000)
    _perturb(m)
    up = m.upper_mask()
    assert up.sum() > 512 and (~up).sum() > 512
    m.refresh_keys()
    ku, kl = m.keys_u, m.keys_l
    assert len(ku) == 512 and len(kl) == 512
    assert len(set(ku.tolist())) == 512 and len(set(kl.tolist())) == 512
    assert bool(up[ku].all()) and not bool(up[kl].any())
    # default: the lower keys are drawn ∝ correlation weight, reproducibly for one seed
    again = select_keys(m, m.gaussians.means.detach(), torch.nonzero(up).reshape(-1),
                        torch.nonzero(~up).reshape(-1), 512, m.cfg.seed)
    assert torch.equal(again[0], ku) and torch.equal(again[1], kl)
    E = m.embed(m.gaussians.means.detach())
    il = torch.nonzero(~up).reshape(-1)
    corr = m.w_gm(E[ku], E[il]).sum(0).detach()
    # "top": the 512 largest correlation weights towards the upper keys
    _, top = select_keys(m, m.gaussians.means.detach(), torch.nonzero(up).reshape(-1), il, 512, 0, "top")
    chosen = torch.isin(il, top)
    assert corr[chosen].min() >= corr[~chosen].max() - 1e-6
    # farthest-point sampling spreads the upper keys: every upper Gaussian is near one
    d = torch.cdist(m.gaussians.means.detach()[up], m.gaussians.means.detach()[ku]).min(1).values
    assert float(d.max()) < 0.03  # sphere radius 0.1: 512 well-spread keys on a hemisphere


def test_lower_keys_are_drawn_in_proportion_to_correlation_weight():
    """Inclusion frequency over many seeds follows the weight: the heaviest tenth of the lower
    Gaussians is drawn clearly more often than the lightest tenth, yet every region gets keys
    (unlike "top", which never picks the light ones)."""
    m = _model(3000)
    _perturb(m)
    with torch.no_grad():  # sharper embeddings: correlation weights that differ
        m.mlp_gm[-1].weight.mul_(4.0)
    X = m.gaussians.means.detach()
    up = m.upper_mask()
    iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
    ku, _ = select_keys(m, X, iu, il, 512, 0)
    E = m.embed(X)
    corr = m.w_gm(E[ku], E[il]).sum(0).detach()
    order = torch.argsort(corr)
    tenth = len(il) // 10
    light, heavy = order[:tenth], order[-tenth:]
    hits = torch.zeros(len(il))
    for seed in range(40):
        _, kl = select_keys(m, X, iu, il, 512, seed)
        assert len(kl) == 512 and len(set(kl.tolist())) == 512
        hits += torch.isin(il, kl).float()
    rate = hits / 40
    ratio = float(corr[heavy].mean() / corr[light].mean())
    assert ratio > 1.5, ratio  # the test needs weights that differ
    assert rate[heavy].mean() > 1.2 * rate[light].mean()
    assert rate[light].mean() > 0.05
    _, top = select_keys(m, X, iu, il, 512, 0, "top")
    assert not bool(torch.isin(il[light], top).any())
    with pytest.raises(AvatarError):
        select_keys(m, X, iu, il, 512, 0, "largest")
    with pytest.raises(AvatarError):
        HFMConfig(lower_keys="largest")


@pytest.mark.parametrize("detach,latent", [(False, False), (True, False), (True, True)])
def test_detach_lower_keeps_upper_face_errors_out_of_the_lower_networks(detach, latent):
    m = _model(3000, detach_lower=detach, map_latent_grad=latent, global_pose=False)  # θ reaches U only by the mapping
    _perturb(m)
    up = m.upper_mask()
    theta = torch.randn(1, 128, requires_grad=True)
    g = m.deform(theta)
    with torch.no_grad():  # the same Gaussians whichever way the gradients go
        ref = _model(3000, global_pose=False)
        ref.load_state_dict(m.state_dict())
        assert torch.allclose(ref.deform(theta).means, g.means, atol=1e-7)
    g.means[up].pow(2).sum().backward()  # a loss on the upper face only
    lower_grad = sum(float(p.grad.abs().sum()) for p in m.mlp_x.parameters() if p.grad is not None)
    mapping_grad = sum(float(p.grad.abs().sum()) for p in m.mlp_mapping.parameters())
    assert mapping_grad > 0
    assert (lower_grad == 0) == detach
    # the latent learns from the upper face end to end, or with map_latent_grad
    assert (theta.grad is not None and float(theta.grad.abs().sum()) > 0) == (latent or not detach)


def test_mapping_reads_the_lower_deformations_by_their_running_rms():
    m = _model(2000, feat_norm=False)  # f_U's own statistics would differ between the two units
    _perturb(m)
    m.train()
    up = m.upper_mask()
    E = m.embed(m.gaussians.means.detach())
    eU, eL = E[up][:300], E[~up][:400]
    pL = torch.randn(400, 10) * torch.logspace(-3, -1, 10)  # channels of very different size
    # a frozen p_L (the static warm-up, or evaluation) leaves the statistics alone
    with torch.no_grad():
        m.map_params(eU, eL, pL)
    assert float(m.p_steps) == 0 and float(m.p_ms.abs().sum()) == 0
    assert torch.equal(m.lower_rms(pL, False), torch.ones(10))  # no statistics yet: p_L as it is
    out = {}
    for c in (1.0, 10.0):  # the same deformations in other units
        m.p_ms.zero_(), m.p_steps.zero_()
        out[c] = m.map_params(eU, eL, (c * pL).requires_grad_())
        # bias-corrected: after one update the RMS is the current one, per channel
        assert torch.allclose(m.lower_rms(pL, False), c * pL.pow(2).mean(0).sqrt(), rtol=1e-5, atol=2e-6)
    assert float(m.p_steps) == 1
    assert torch.allclose(out[1.0], out[10.0], atol=1e-4)
    m.eval()
    before = m.p_ms.clone()
    m.map_params(eU, eL, (3 * pL).requires_grad_())
    assert torch.equal(m.p_ms, before)
    raw = _model(2000, map_norm=False, feat_norm=False)
    _perturb(raw)  # and without it, units matter
    with torch.no_grad():
        assert not torch.allclose(raw.map_params(eU, eL, pL), raw.map_params(eU, eL, 100 * pL), atol=1e-3)


def test_feature_standardisation_by_running_statistics(tmp_path):
    m = _model(2000, feat_norm=True)
    m.train()
    g = torch.Generator().manual_seed(3)
    mean = torch.linspace(-1, 1, 32)
    std = torch.logspace(-2, 0, 32)
    std[0] = 0.0  # a channel that never varies
    f = mean + std * torch.randn(64, 32, generator=g)
    assert torch.equal(m.standardise_features(f), f)  # no statistics yet: f_U as it is
    m.standardise_features(f.detach())  # frozen features (warm-up, evaluation): no update
    assert float(m.f_steps) == 0
    for _ in range(400):  # a stream of frames: the EMA sees the spread across them
        m.standardise_features((mean + std * torch.randn(64, 32, generator=g)).requires_grad_())
    assert float(m.f_steps) == 400
    m.eval()
    z = m.standardise_features(mean + std * torch.randn(4000, 32, generator=g))
    # the varying channels come out centred with unit spread (the floor adds 1% of the mean square)
    floor = (1 + 0.01 * (mean[1:] ** 2 + std[1:] ** 2) / std[1:] ** 2).sqrt()
    assert torch.allclose(z[:, 1:].mean(0), torch.zeros(31), atol=0.15)
    assert torch.allclose(z[:, 1:].std(0) * floor, torch.ones(31), rtol=0.15)
    # a constant channel is not blown up: a change of its RMS moves it by at most ten
    shifted = m.standardise_features(torch.full((1, 32), 0.0) + mean + torch.cat([mean[:1].abs(), torch.zeros(31)]))
    assert shifted[0, 0].abs() <= 10 + 1e-3
    before = m.f_mean.clone()
    m.standardise_features((mean + torch.randn(8, 32)).requires_grad_())  # eval: statistics frozen
    assert torch.equal(m.f_mean, before)
    save_hfm(m, tmp_path / "m")
    assert torch.equal(load_hfm(tmp_path / "m").f_ms, m.f_ms)


def test_refit_statistics_are_plain_means_over_the_frames():
    m = _model(2500)  # map_norm and feat_norm on, keys sampled
    _perturb(m, std=0.1)
    m.refresh_keys()
    g = torch.Generator().manual_seed(5)
    crops, boxes = torch.rand(5, 3, 128, 128, generator=g), torch.rand(5, 3, generator=g)
    with torch.no_grad():  # stale statistics, as the last training steps leave them
        m.p_ms.fill_(7.0), m.p_steps.fill_(30), m.f_mean.fill_(3.0), m.f_ms.fill_(20.0), m.f_steps.fill_(30)
    m.refit_statistics(crops, boxes)
    X = m.gaussians.means.detach()
    E = m.embed(X)
    with torch.no_grad():
        pK = [m.lower_params(E[m.keys_l], m.encoder(crops[t:t + 1], boxes[t:t + 1])) for t in range(5)]
        want_ms = torch.stack([p.pow(2).mean(0) for p in pK]).mean(0)
        assert torch.allclose(m.lower_rms(pK[0], False), want_ms.sqrt() + 1e-6, rtol=1e-5)  # no bias left
        fU = [m.map_features(E[m.keys_u], E[m.keys_l], p) for p in pK]  # reads p_L by the new RMS
        assert torch.allclose(m.f_mean, torch.stack([f.mean(0) for f in fU]).mean(0), atol=1e-6)
        assert torch.allclose(m.f_ms, torch.stack([f.pow(2).mean(0) for f in fU]).mean(0), rtol=1e-5, atol=1e-7)
    assert m._refit is None
    before = m.deform(m.encoder(crops[:1], boxes[:1])).means
    m.refit_statistics(crops, boxes)  # the same weights and frames: the same statistics
    assert torch.allclose(m.deform(m.encoder(crops[:1], boxes[:1])).means, before, atol=1e-6)
    _model(600, gaussian_mapping=False).refit_statistics(crops, boxes)  # nothing to refit


def test_mapping_heads_decode_each_parameter_as_eq_2_does(tmp_path):
    three, one = _model(1500), _model(1500, mapping_heads=1)
    _perturb(three)
    h = torch.randn(50, three.mlp_mapping.x[0].in_features)
    with torch.no_grad():
        out = three.mlp_mapping(h)
        heads = three.mlp_mapping
        assert torch.equal(out, torch.cat([heads.x(h), heads.s(h), heads.r(h)], -1)) and out.shape == (50, 10)
    # each head is as wide as the eq.-2 network for its parameter; one head shares a single MLP
    width = [m.out_features for m in three.mlp_mapping.x if isinstance(m, torch.nn.Linear)]
    assert width == [three.cfg.hidden, three.cfg.hidden, 3]
    n = lambda mod: sum(p.numel() for p in mod.parameters())  # noqa: E731
    assert n(three.mlp_mapping) - n(one.mlp_mapping) == 2 * n(one.mlp_mapping) - 20 * (three.cfg.hidden + 1)
    # identity at initialisation, whatever the features
    assert torch.equal(_model(1500).mlp_mapping(h), torch.zeros(50, 10))
    # folders written before the field have one head
    save_hfm(one, tmp_path / "old")
    meta = json.loads((tmp_path / "old" / "config.json").read_text())
    del meta["config"]["mapping_heads"]
    (tmp_path / "old" / "config.json").write_text(json.dumps(meta))
    assert load_hfm(tmp_path / "old").cfg.mapping_heads == 1
    with pytest.raises(AvatarError, match="mapping_heads"):
        HFMConfig(mapping_heads=2)


def test_fewer_gaussians_than_keys_uses_them_all():
    m = _model(300)
    m.refresh_keys()
    up = m.upper_mask()
    assert len(m.keys_u) == int(up.sum()) and len(m.keys_l) == int((~up).sum())


def test_w_dist_rows_sum_to_one_and_keys_map_to_themselves():
    P = torch.rand(500, 3, dtype=torch.float64)
    keys = farthest_point_sampling(P, 64)
    j, w = inverse_distance_weights(P, P[keys], k=8)
    assert j.shape == (500, 8) and w.shape == (500, 8)
    assert torch.all(w >= 0)
    assert torch.allclose(w.sum(1), torch.ones(500, dtype=torch.float64), atol=1e-12)
    # a key's own row puts (almost) all weight on itself
    assert torch.all(w[keys, 0] > 1 - 1e-6) and torch.equal(j[keys, 0], torch.arange(64))
    # a point halfway between two keys (and far from the rest) weighs them equally
    Q = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [0.5, 0, 0]], dtype=torch.float64)
    j2, w2 = inverse_distance_weights(Q[2:], Q[:2], k=2)
    assert torch.allclose(w2, torch.full((1, 2), 0.5, dtype=torch.float64))


def test_sampling_with_every_gaussian_a_key_equals_the_dense_mapping():
    m = _model(600, n_keys=1000)
    _perturb(m)
    dense = _model(600, n_keys=1000, sampling=False)
    dense.load_state_dict(m.state_dict())
    theta = torch.randn(1, 128)
    with torch.no_grad():
        a, b = m.deform(theta), dense.deform(theta)
    assert torch.allclose(a.means, b.means, atol=1e-6)
    assert torch.allclose(a.log_scales, b.log_scales, atol=1e-6)


def test_upsampling_features_runs_the_mapping_mlp_at_every_upper_gaussian():
    m = _model(3000, upsample="features", global_pose=False)
    _perturb(m, std=0.2)
    params = _model(3000, upsample="params", global_pose=False)
    params.load_state_dict(m.state_dict())
    theta = torch.randn(1, 128)
    with torch.no_grad():
        a, b = m.deform(theta), params.deform(theta)
        X = m.gaussians.means
        up = m.upper_mask()
        iu = torch.nonzero(up).reshape(-1)
        E = m.embed(X)
        p = m.lower_params(E, theta)
        fk = m.map_features(E[m.keys_u], E[m.keys_l], p[m.keys_l])
        j, w = m.wdist
        want = m.mlp_mapping(torch.cat([E[iu], (fk[j] * w[..., None]).sum(1)], -1))
    assert torch.equal(m.keys_u, params.keys_u) and torch.equal(m.keys_l, params.keys_l)
    # p_U = MLP_mapping(γ(x_u), Σ_k W_dist[u, k] f_k) at each upper Gaussian
    assert torch.allclose((a.means - X)[iu] / (m.scale * 0.1), want[:, :3], atol=1e-5)
    assert torch.allclose(a.log_scales[iu] - m.gaussians.log_scales[iu], want[:, 3:6], atol=1e-5)
    # both spread the same key values: equal at the keys, different between them
    key = torch.isin(iu, m.keys_u)
    assert torch.allclose(a.means[iu[key]], b.means[iu[key]], atol=1e-5)
    assert (a.means[iu[~key]] - b.means[iu[~key]]).norm(dim=1).max() > 1e-4
    assert torch.equal(a.means[~up], b.means[~up])


def test_segregation_drops_exactly_the_crossing_children():
    m = 0.004
    s = SegregationStrategy(DensityConfig(), 1.0, Y_T, m, torch.tensor([True, False]))
    y = torch.tensor([Y_T - m - 1e-4, Y_T - m + 1e-4, Y_T + 0.01,     # children of the upper parent
                      Y_T + m + 1e-4, Y_T + m - 1e-4, Y_T - 0.01])    # children of the lower parent
    parents = torch.tensor([0, 0, 0, 1, 1, 1])
    means = torch.zeros(6, 3)
    means[:, 1] = y
    keep = s.filter_split(None, parents, {"means": means})
    assert keep.tolist() == [False, True, True, False, True, True]
    assert s.dropped == 2


def test_segregation_during_a_split_and_labels_follow():
    n = 4
    X = torch.tensor([[0.0, 0.002, 0], [0.1, 0.05, 0], [0.0, -0.002, 0], [0.1, -0.05, 0]])
    g = Gaussians(X, torch.full((n, 3), math.log(0.02)), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                  torch.zeros(n), torch.rand(n, 3))
    upper = X[:, 1] > 0
    s = SegregationStrategy(DensityConfig(split_n=64), 1.0, 0.0, 0.001, upper)
    torch.manual_seed(0)
    s.split(g, None, torch.arange(n))
    assert s.dropped > 0  # σ = 2 cm around points 2 mm from the plane: many children cross it
    assert len(s.upper) == len(g)
    y = g.means.detach()[:, 1]
    assert torch.all(y[s.upper] >= -0.001) and torch.all(y[~s.upper] <= 0.001)


def test_boundary_loss():
    y = torch.tensor([0.01, 0.02, -0.01, -0.03])
    up = torch.tensor([True, True, False, False])
    assert float(boundary_loss(y, up, 0.0)) == 0.0
    y2 = torch.tensor([-0.01, 0.02, 0.03, -0.03])
    assert math.isclose(float(boundary_loss(y2, up, 0.0)), 0.01 / 2 + 0.03 / 2, rel_tol=1e-6)


@pytest.mark.parametrize("ablation", sorted(ABLATIONS))
def test_zero_latent_and_identity_mlps_leave_the_canonical_gaussians(ablation):
    m = _model(1500, **ABLATIONS[ablation])
    g = m.gaussians
    with torch.no_grad():
        for theta in (torch.zeros(1, 128), torch.randn(1, 128)):  # zero-initialised last layers
            d = m.deform(theta)
            assert torch.allclose(d.means, g.means, atol=1e-7)
            assert torch.allclose(d.log_scales, g.log_scales, atol=1e-7)
            q = g.quats / g.quats.norm(dim=-1, keepdim=True)
            assert torch.allclose(d.quats, q, atol=1e-7)
        _perturb(m)  # and the test can fail: trained weights do move them
        assert not torch.allclose(m.deform(torch.randn(1, 128)).means, g.means, atol=1e-5)


def test_without_the_mapping_one_deformation_field_moves_both_halves():
    """The paper's ablation: the upper face is deformed by the lower face's networks (eq. 2) —
    the same function of (position, θ) everywhere, no extra weights; "separate" adds its own MLP."""
    shared = _model(1200, **ABLATIONS["no_gaussian_feature_mapping"])
    assert not hasattr(shared, "mlp_up") and not hasattr(shared, "mlp_gm")
    _perturb(shared)
    theta = torch.randn(1, 128)
    X = shared.gaussians.means.detach()
    shared.cfg = replace(shared.cfg, global_pose=False)
    with torch.no_grad():
        d = shared.deform(theta)
        p = shared.lower_params(shared.embed(X), theta)  # eq. 2 on every Gaussian
    up = shared.upper_mask()
    assert up.any() and (~up).any()
    assert torch.allclose(d.means, X + p[:, :3] * shared.scale * 0.1, atol=1e-6)
    assert torch.allclose(d.log_scales, shared.gaussians.log_scales + p[:, 3:6], atol=1e-6)
    sep = _model(1200, **ABLATIONS["no_gaussian_feature_mapping_separate"])
    n_shared = sum(q.numel() for q in shared.parameters())
    assert sum(q.numel() for q in sep.parameters()) - n_shared == sum(q.numel() for q in sep.mlp_up.parameters())
    _perturb(sep)
    with torch.no_grad():
        sep.cfg = replace(sep.cfg, global_pose=False)
        d = sep.deform(theta)
        pl = sep.lower_params(sep.embed(X), theta)
    up = sep.upper_mask()
    assert torch.allclose(d.means[~up], X[~up] + pl[~up, :3] * sep.scale * 0.1, atol=1e-6)
    assert not torch.allclose(d.means[up], X[up] + pl[up, :3] * sep.scale * 0.1, atol=1e-4)
    with pytest.raises(AvatarError, match="unmapped_upper"):
        HFMConfig(unmapped_upper="own")


def test_global_pose_is_a_rigid_motion_about_the_centre():
    m = _model(500, pose_residual=True)  # the residual pose MLP (off by default)
    w, t = torch.tensor([0.0, 0.3, 0.0]), torch.tensor([0.1, 0.0, -0.2])
    with torch.no_grad():
        m.mlp_pose[-1].bias.copy_(torch.cat([w, t]))
        d = m.deform(torch.zeros(1, 128))
    c, s = m.center, float(m.scale)
    R = torch.tensor([[math.cos(0.3), 0, math.sin(0.3)], [0, 1, 0], [-math.sin(0.3), 0, math.cos(0.3)]])
    want = (m.gaussians.means - c) @ R.T + c + t * s * 0.1
    assert torch.allclose(d.means, want, atol=1e-6)


def test_without_the_pose_residual_the_pose_read_from_the_crop_is_the_pose():
    """``pose_residual=False``: no MLP_pose; the head pose the model reads from the crop (or the
    one given) moves the Gaussians alone, and an older model folder's config loads with it on."""
    m = _model(500, pose_residual=False)
    assert not hasattr(m, "mlp_pose") and m.predicts_head_pose
    w, t = torch.tensor([0.0, 0.2, 0.0]), torch.tensor([0.05, 0.0, 0.1])
    with torch.no_grad():
        m.mlp_head_pose[-1].bias.copy_(torch.cat([w, t]))
        theta = torch.zeros(1, 128)
        read = m.deform(theta)
        still = m.deform(theta, read_pose=False)
    c, s = m.center, float(m.scale)
    R = torch.tensor([[math.cos(0.2), 0, math.sin(0.2)], [0, 1, 0], [-math.sin(0.2), 0, math.cos(0.2)]])
    assert torch.allclose(read.means, (still.means - c) @ R.T + c + t * s * 0.1, atol=1e-6)
    assert torch.allclose(still.means, m.gaussians.means, atol=1e-6)  # zero last layers: no deformation
    with pytest.raises(AvatarError, match="registration_landmarks"):
        HFMConfig(registration_landmarks="upper")


def test_encoder_shapes_and_config_errors():
    m = _model(200)
    assert m.encoder(torch.rand(2, 3, 128, 128)).shape == (2, 128)
    with pytest.raises(AvatarError):
        HFMConfig(crop=100)
    with pytest.raises(AvatarError):
        HFMConfig.from_dict({"bogus": 1})
    with pytest.raises(AvatarError, match="map_norm_momentum"):
        HFMConfig(map_norm_momentum=0)
    with pytest.raises(AvatarError, match="upsample"):
        HFMConfig(upsample="keys")


def test_vgg_perceptual_from_local_weights(tmp_path):
    from safetensors.torch import save_file

    v = VGGPerceptual.__new__(VGGPerceptual)
    torch.nn.Module.__init__(v)
    layers, c = [], 3
    for k in (64, 64, "M", 128, 128, "M", 256, 256, 256):
        if k == "M":
            layers.append(torch.nn.MaxPool2d(2))
        else:
            layers += [torch.nn.Conv2d(c, k, 3, padding=1), torch.nn.ReLU()]
            c = k
    sd = {f"features.{k}": t for k, t in torch.nn.Sequential(*layers).state_dict().items()}
    save_file(sd, str(tmp_path / "vgg.safetensors"))
    vgg = VGGPerceptual(tmp_path / "vgg.safetensors")
    a = torch.rand(1, 3, 32, 32)
    assert float(vgg(a, a)) == 0.0
    assert float(vgg(a, a.flip(-1))) > 0
    (tmp_path / "bad.safetensors").write_bytes(b"not weights")
    with pytest.raises(AvatarError):
        VGGPerceptual(tmp_path / "bad.safetensors")
    save_file({"features.0.weight": torch.zeros(3)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(AvatarError):
        VGGPerceptual(tmp_path / "other.safetensors")


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    out = tmp_path_factory.mktemp("hmd")
    return make_synthetic_hmd(out, frames=12, res=64, n_vertices=2000, quiet=True)


def test_synthetic_videos_and_loader(videos):
    reg, use = videos
    r, u = load_video(reg, need_mesh=True), load_video(use)
    assert len(r) + len(u) == 12 and len(u) == 2
    assert r.frames.shape[1:] == (64, 64, 3) and r.masks.any()
    assert u.gt is not None and u.hmd_masks is not None and u.hmd_masks.any()
    # the headset hides the eyes, not the mouth
    lm = {n: u.landmarks[0][u.names.index(n)] for n in ("eye_left_center", "mouth_left")}
    ij = lambda p: (int(round(p[1] - 0.5)), int(round(p[0] - 0.5)))  # noqa: E731
    assert u.hmd_masks[0][ij(lm["eye_left_center"])] and not u.hmd_masks[0][ij(lm["mouth_left"])]
    # in the usage video the occluded pixels differ from the unoccluded truth; elsewhere they agree
    diff = np.abs(u.frames[0] - u.gt[0]).max(-1)
    assert diff[u.hmd_masks[0]].mean() > 0.1 and diff[~u.hmd_masks[0]].mean() < 0.02
    crops = u.crops(128)
    assert crops.shape == (2, 3, 128, 128) and 0 <= crops.min() and crops.max() <= 1


def test_rest_pose_frames_differ_from_the_truth_only_in_the_upper_face(videos):
    _, use = videos
    u = load_video(use)
    meta = json.loads((use / "meta.json").read_text())["frames"]
    assert u.gt_static_upper is not None and u.gt_static_upper.shape == u.gt.shape
    for t, fr in enumerate(meta):
        d = np.abs(u.gt[t] - u.gt_static_upper[t]).max(-1)
        below = np.nonzero(u.hmd_masks[t].any(1))[0].max() + 1  # first row under the headset
        assert d[below:].max() == 0  # the lower face is the same
        if not any(fr["expression"][k] for k in UPPER_EXPRESSIONS):
            assert d.max() == 0
        else:
            assert d.max() > 0


def test_expression_region_metrics():
    """The expression region is exactly the occluded pixels the upper expression changes; a render
    equal to the rest-pose frame scores the rest-pose reference there, the truth scores inf."""
    rng = np.random.default_rng(0)
    T, H, W = 2, 24, 24
    gt = rng.uniform(0.2, 0.8, (T, H, W, 3)).astype(np.float32)
    hmd = np.zeros((T, H, W), bool)
    hmd[:, :12] = True
    rest = gt.copy()
    rest[0, 3:7, 5:10] += 0.1   # 20 pixels: an expression in frame 0
    rest[1, 2:4, 2:4] += 0.1    # 4 pixels: below EXPRESSION_MIN_PIXELS
    rest[:, 18:20] += 0.1       # outside the headset: not scored
    v = HMDVideo(gt, np.ones((T, H, W), bool), np.zeros((T, 4, 2)), list(LOWER_FACE_LANDMARKS), None, 0.0,
                 hmd_masks=hmd, gt=gt, gt_static_upper=rest)
    m = hmd_metrics(rest, v)
    assert m["expression_frames"] == 1 and m["expression_pixels"] == 12.0  # (20 + 4) / 2
    assert m["psnr_expression"] == pytest.approx(m["psnr_expression_rest"]) == pytest.approx(20.0, abs=1e-4)
    assert m["psnr_occluded"] > m["psnr_expression"]
    assert hmd_metrics(gt, v)["psnr_expression"] == float("inf")
    half = gt.copy()
    half[0, 3:7, 5:10] += 0.05  # halfway to the truth: 6 dB better than the rest pose
    assert hmd_metrics(half, v)["psnr_expression"] == pytest.approx(26.02, abs=0.01)
    with pytest.raises(AvatarError, match="do not match"):
        hmd_metrics(gt[:, :10], v)


def test_occluded_outline_metrics():
    """The occluded region splits into the face's outline (1 px band inside the face's edge, not
    the image border) and its interior: a head drawn one pixel low loses at the outline far more
    than inside; an error only along the outline leaves the interior perfect."""
    T, H, W = 1, 40, 40
    yy, xx = np.mgrid[:H, :W]
    face = (yy - 24.0) ** 2 + (xx - 20.0) ** 2 <= 15.0 ** 2
    face[-3:] = (np.abs(xx - 20) <= 6)[-3:]  # a neck that leaves through the image border
    shade = 0.4 + 0.2 * np.sin(xx / 3.0)[..., None] * np.array([1.0, 0.8, 0.6])
    gt = np.where(face[..., None], shade, 0.0).astype(np.float32)[None]
    hmd = np.zeros((T, H, W), bool)
    hmd[:, :22] = True  # the headset hides the crown
    v = HMDVideo(gt, face[None], np.zeros((T, 4, 2)), list(LOWER_FACE_LANDMARKS), None, 0.0, hmd_masks=hmd, gt=gt)
    band = face & ~ndimage.binary_erosion(face, iterations=1, border_value=1)
    assert band[-1].sum() == 2  # the image border is no outline: only the neck's sides are
    m = hmd_metrics(gt, v)
    assert m["psnr_occluded_outline"] == m["psnr_occluded_interior"] == float("inf")
    low = np.roll(gt, 1, axis=1)  # the head one pixel low
    m = hmd_metrics(low, v)
    assert m["psnr_occluded_outline"] < m["psnr_occluded_interior"] - 6
    assert m["psnr_occluded_outline"] < m["psnr_occluded"] < m["psnr_occluded_interior"]
    rim = np.where(band[None, ..., None], 0.0, gt)  # wrong only along the outline
    m = hmd_metrics(rim, v)
    assert m["psnr_occluded_interior"] == float("inf") and np.isfinite(m["psnr_occluded_outline"])
    n = (band & hmd[0]).sum()
    mse = ((gt[0] - rim[0]) ** 2)[band & hmd[0]].mean()
    assert n > 20 and m["psnr_occluded_outline"] == pytest.approx(-10 * np.log10(mse))
    v0 = HMDVideo(gt, face[None], np.zeros((T, 4, 2)), list(LOWER_FACE_LANDMARKS), None, 0.0,
                  hmd_masks=np.zeros_like(hmd), gt=gt)
    assert np.isnan(hmd_metrics(low, v0)["psnr_occluded_outline"])  # nothing occluded: no figure


def test_lower_face_crop_contains_the_mouth():
    pts = np.array([[60.0, 50], [50, 70], [70, 70], [60, 90]])  # nose, mouth l/r, chin
    cx, cy, side = lower_face_box(pts)
    for x, y in pts[1:]:
        assert abs(x - cx) < side / 2 and abs(y - cy) < side / 2
    img = np.zeros((128, 128, 3), np.float32)
    img[68:73, 48:73] = 1.0  # the mouth
    c = crop_lower_face(img, pts, 64)
    assert c.shape == (3, 64, 64) and c.max() > 0.9


def test_loader_errors(videos, tmp_path):
    import shutil

    from geoface.errors import CaptureError

    reg, _ = videos
    with pytest.raises(CaptureError, match="no frames"):
        load_video(tmp_path)
    bad = tmp_path / "bad"
    shutil.copytree(reg, bad)
    n = len(list((bad / "frames").glob("*.png")))
    (bad / "landmarks.json").write_text(json.dumps({"names": ["nose_tip"], "points": [[[0, 0]]] * n}))
    with pytest.raises(CaptureError, match="missing landmarks"):
        load_video(bad)
    (bad / "landmarks.json").write_text(json.dumps({"names": ["nose_tip"], "points": []}))
    with pytest.raises(CaptureError, match="points must be"):
        load_video(bad)
    shutil.rmtree(bad)
    shutil.copytree(reg, bad)
    cam = json.loads((bad / "camera.json").read_text())
    cam["width"] = 100
    (bad / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(CaptureError, match="camera.json"):
        load_video(bad)


def test_a_few_training_steps_lower_the_loss_save_load_and_evaluate(videos, tmp_path):
    reg, use = videos
    cfg = HFMConfig(iters=40, densify=False, seed=0)
    info = train_hfm(reg, tmp_path / "m", cfg, progress=False, log=None)
    h = [r["loss"] for r in info["history"]]
    assert np.mean(h[-10:]) < 0.85 * np.mean(h[:10])
    m = load_hfm(tmp_path / "m")
    video = load_video(use)
    ev = evaluate_hmd(m, video)
    assert ev["frames"] == 2 and ev["fps"] > 0 and 5 < ev["psnr_face"] < 60
    # the saved model reproduces the trained one
    info2 = train_hfm(reg, tmp_path / "m2", replace(cfg, iters=1), progress=False, log=None)
    assert info2["n_gaussians"] == 2000
    crop = torch.tensor(video.crops(128)[:1])
    m2 = load_hfm(tmp_path / "m")
    with torch.no_grad():
        assert torch.equal(m(crop).means, m2(crop).means)
    # a corrupt checkpoint is a one-line error
    (tmp_path / "m" / "model.safetensors").write_bytes(b"\0" * 64)
    with pytest.raises(AvatarError, match="cannot read weights"):
        load_hfm(tmp_path / "m")


def test_static_warm_up_freezes_the_networks_then_trains_them(videos, tmp_path):
    from geoface.hfm import build_model

    reg, _ = videos
    cfg = HFMConfig(iters=10, warmup=0.6, densify=False, seed=3)
    info = train_hfm(reg, tmp_path / "w", cfg, progress=False, log=None)
    assert info["warmup_steps"] == 6
    assert [r["nets"] for r in info["history"]] == [False] * 6 + [True] * 4
    torch.manual_seed(cfg.seed)
    init = build_model(load_video(reg, need_mesh=True), cfg)
    trained = load_hfm(tmp_path / "w")
    assert not torch.equal(init.encoder.out.weight, trained.encoder.out.weight)
    # without warm-up the networks train from the first step
    info0 = train_hfm(reg, tmp_path / "w0", replace(cfg, iters=3, warmup=0.0), progress=False, log=None)
    assert all(r["nets"] for r in info0["history"]) and info0["warmup_steps"] == 0
    with pytest.raises(AvatarError, match="warmup"):
        HFMConfig(warmup=1.0)


def test_ema_must_be_below_one():
    with pytest.raises(AvatarError, match="ema"):
        HFMConfig(ema=1.0)


def test_the_saved_model_averages_the_weights_of_the_last_steps(videos, tmp_path, monkeypatch):
    reg, _ = videos
    snaps = []
    update = WeightAverage.update

    def spy(self, module):
        snaps.append({n: p.detach().clone() for n, p in module.named_parameters()})
        update(self, module)

    monkeypatch.setattr(WeightAverage, "update", spy)
    cfg = HFMConfig(iters=12, warmup=0.25, densify=False, seed=0, ema=0.7)
    info = train_hfm(reg, tmp_path / "a", cfg, progress=False, log=None)
    assert info["averaged_steps"] == len(snaps) == 9  # every step once the networks train (step 3 on)
    w = 0.7 ** torch.arange(8, -1, -1, dtype=torch.float64)
    w = w / w.sum()
    sd = load_hfm(tmp_path / "a").state_dict()
    for name in ("encoder.out.weight", "mlp_x.0.weight", "mlp_mapping.x.0.weight", "gaussians.colors", "gaussians.means"):
        want = sum(float(wi) * s[name] for wi, s in zip(w, snaps))
        assert torch.allclose(sd[name], want, atol=1e-6), name
        assert not torch.allclose(sd[name], snaps[-1][name], atol=1e-6), name  # not the last step's weights
    # with density control the average starts once it has stopped adding and removing Gaussians
    snaps.clear()
    info = train_hfm(reg, tmp_path / "b", replace(cfg, iters=20, densify=True), progress=False, log=None)
    assert info["averaged_steps"] == len(snaps) == 20 - int(0.6 * 20)
    assert {len(s["gaussians.means"]) for s in snaps} == {info["n_gaussians"]}
    # ema=0 saves the last step's weights
    snaps.clear()
    assert train_hfm(reg, tmp_path / "c", replace(cfg, ema=0.0), progress=False, log=None)["averaged_steps"] == 0
    assert not snaps


def test_expression_motion_is_zero_at_the_identity_and_follows_the_crop(videos):
    from geoface.hfm import build_model, expression_motion

    reg, use = videos
    torch.manual_seed(0)
    m = build_model(load_video(reg, need_mesh=True), HFMConfig())
    video = load_video(reg)  # ten frames with different expressions
    assert max(expression_motion(m, video).values()) < 1e-4  # float32 rounding only
    _perturb(m)
    mo = expression_motion(m, video)
    assert mo["lower_motion_mm"] > 1e-3 and mo["upper_motion_mm"] > 1e-3
    # every frame the same crop: nothing moves
    same = load_video(reg)
    same.frames[:] = same.frames[:1]
    same.landmarks[:] = same.landmarks[:1]
    assert max(expression_motion(m, same).values()) < 1e-4


def test_save_load_round_trip_with_sampling_keys(tmp_path):
    m = _model(2500)
    _perturb(m)
    save_hfm(m, tmp_path)
    m2 = load_hfm(tmp_path)
    theta = torch.randn(1, 128)
    with torch.no_grad():
        assert torch.allclose(m.deform(theta).means, m2.deform(theta).means, atol=1e-6)
    # a folder written before map_norm existed reads p_L raw
    old = _model(2500, map_norm=False)
    save_hfm(old, tmp_path / "old")
    meta = json.loads((tmp_path / "old" / "config.json").read_text())
    del meta["config"]["map_norm"], meta["config"]["map_norm_momentum"], meta["config"]["detach_lower"]
    (tmp_path / "old" / "config.json").write_text(json.dumps(meta))
    old_cfg = load_hfm(tmp_path / "old").cfg
    assert old_cfg.map_norm is False
    assert old_cfg.detach_lower is False and m2.cfg.detach_lower is True
    # folders of the variant without the mapping written before unmapped_upper: by their weights
    for name, want in (("no_gaussian_feature_mapping_separate", "separate"), ("no_gaussian_feature_mapping", "shared")):
        save_hfm(_model(600, **ABLATIONS[name]), tmp_path / name)
        meta = json.loads((tmp_path / name / "config.json").read_text())
        del meta["config"]["unmapped_upper"]
        (tmp_path / name / "config.json").write_text(json.dumps(meta))
        assert load_hfm(tmp_path / name).cfg.unmapped_upper == want
    # the registration's ICT identity (a headset video is tracked as that head) survives a round trip;
    # a malformed one is a one-line error
    m.ict_identity = [0.5, -1.25, 2.0]
    save_hfm(m, tmp_path / "ident")
    assert load_hfm(tmp_path / "ident").ict_identity == [0.5, -1.25, 2.0] and m2.ict_identity is None
    meta = json.loads((tmp_path / "ident" / "config.json").read_text())
    meta["ict_identity"] = [0.5, "x"]
    (tmp_path / "ident" / "config.json").write_text(json.dumps(meta))
    with pytest.raises(AvatarError, match="ict_identity must be up to 100 finite weights"):
        load_hfm(tmp_path / "ident")
    cfg = json.loads((tmp_path / "config.json").read_text())
    cfg["n_gaussians"] = 7
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(AvatarError):
        load_hfm(tmp_path)


def test_cli_end_to_end_and_errors(videos, tmp_path, capsys):
    from geoface.cli import main
    from geoface.cli.hmd import ABLATION_NAMES

    assert set(ABLATION_NAMES) == set(ABLATIONS)
    reg, use = videos
    md = tmp_path / "model"
    assert main(["hmd", "train", str(reg), "-o", str(md), "--iters", "5", "--no-densify", "-q"]) == 0
    assert main(["hmd", "train", str(reg), "-o", str(md), "--iters", "5", "-q"]) == 2  # no overwrite
    assert main(["hmd", "train", str(reg), "-o", str(tmp_path / "m4"), "--iters", "5", "--ema", "1.5", "-q"]) == 2
    assert not (tmp_path / "m4" / "model.safetensors").exists()
    # the paper's elements as options; saved in the model's config
    m5 = tmp_path / "m5"
    assert main(["hmd", "train", str(reg), "-o", str(m5), "--iters", "3", "--no-densify", "--map-theta", "--gm-input",
                 "xsr", "--pm-per-component", "--split-margin", "0.002", "--no-pose-residual", "--pose-landmarks", "lower",
                 "--calibration-weights", "--calibration-expressions", "2", "--pose-refine", "--usage-landmarks", "stable",
                 "--pose-head-detach", "-q"]) == 0
    c5 = load_hfm(m5).cfg
    assert c5.map_theta and c5.gm_input == "xsr" and c5.pm_per_component and c5.split_margin == 0.002
    assert not c5.pose_residual and c5.registration_landmarks == "lower" and c5.pose_calibration_weighted
    assert c5.pose_calibration_expressions == 2 and c5.usage_landmarks == "stable"
    assert c5.image_pose_detach and not load_hfm(md).cfg.image_pose_detach
    assert c5.pose_refine and not (m5 / "registration_poses.npz").exists()  # the folder's pose file: nothing to correct
    assert main(["hmd", "train", str(reg), "-o", str(tmp_path / "m6"), "--gm-input", "s", "-q"]) == 2
    assert main(["hmd", "train", str(reg), "-o", str(tmp_path / "m7"), "--calibration-expressions", "-1", "-q"]) == 2
    assert main(["hmd", "remove", str(md), str(use), "-o", str(tmp_path / "out")]) == 0
    assert len(list((tmp_path / "out" / "frames").glob("*.png"))) == 2
    if importlib.util.find_spec("imageio_ffmpeg"):  # the same as a video (frames composited)
        from geoface.video import probe_video

        assert main(["hmd", "remove", str(md), str(use), "--video", str(tmp_path / "out.mp4"), "--fps", "10"]) == 0
        v = probe_video(tmp_path / "out.mp4")
        assert v["frames"] == 2 and v["fps"] == 10 and abs(v["seconds"] - 0.2) < 0.02 and not v["audio"]
    # the avatar at each frame of the usage video, as standard 3DGS PLY files
    assert main(["hmd", "export", str(md), "--drive", str(use), "-o", str(tmp_path / "ply")]) == 0
    assert sorted(p.name for p in (tmp_path / "ply").iterdir()) == ["frame_00000.ply", "frame_00001.ply"]
    assert main(["hmd", "export", str(md), "-o", str(tmp_path / "ply2")]) == 2  # --drive is required
    if importlib.util.find_spec("viser"):  # the web viewer animates it beside the headset video
        import socket

        from geoface.webview import WebView

        with socket.socket() as sk:
            sk.bind(("127.0.0.1", 0))
            port = sk.getsockname()[1]
        view = WebView([md], drive=use, port=port, quiet=True)
        try:
            d = view.items[0].extra["drive"]
            assert d.model_kind == "hfm" and d.n_frames == 2 and d.frames.shape[0] == 2
        finally:
            view.stop()
    assert main(["hmd", "eval", str(md), str(use), "--json", str(tmp_path / "e.json")]) == 0
    e = json.loads((tmp_path / "e.json").read_text())
    assert {"psnr_occluded", "psnr_occluded_interior", "psnr_occluded_outline"} <= set(e)
    out = capsys.readouterr().out
    assert "FPS" in out and "occluded region" in out
    assert ("outline (the face's edge" in out) == (not math.isnan(e["psnr_occluded_outline"]))
    assert main(["hmd", "eval", str(reg), str(use)]) == 2
    assert main(["hmd", "train", str(use), "-o", str(tmp_path / "m3")]) == 2  # no head mesh
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("geoface: error:") for line in err) and "Traceback" not in "".join(err)
    assert not (tmp_path / "m3").exists()


def test_pose_head_detach_keeps_the_pose_loss_out_of_the_encoder():
    """``image_pose_detach``: the head pose loss trains MLP_head_pose and no encoder weight; without
    it the same loss reaches the encoder."""
    from geoface.hfm.train import head_pose_loss

    crop, box = torch.rand(1, 3, 128, 128), torch.tensor([[0.5, 0.7, 0.4]])
    target = torch.tensor([0.1, -0.2, 0.05, 0.3, 0.0, -0.1])
    grads = {}
    for detach in (False, True):
        m = _model(500, image_pose_detach=detach)
        with torch.no_grad():  # its last layer starts at zero, which would pass no gradient back at all
            m.mlp_head_pose[-1].weight.normal_(0.0, 0.1, generator=torch.Generator().manual_seed(0))
        head_pose_loss(m, m.encoder(crop, box), target).backward()
        enc = [p.grad for p in m.encoder.parameters()]
        head = [p.grad for p in m.mlp_head_pose.parameters()]
        assert all(g is not None and torch.isfinite(g).all() for g in head) and any(g.abs().sum() > 0 for g in head)
        grads[detach] = sum(0.0 if g is None else float(g.abs().sum()) for g in enc)
    assert grads[False] > 0 and grads[True] == 0.0


def test_tracked_head_pose_is_applied_rigidly():
    m = _model(800)
    a = 0.2
    R = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    t, piv = np.array([0.01, -0.02, 0.0]), np.array([0.0, -0.09, 0.0])
    with torch.no_grad():
        d = m.deform(torch.randn(1, 128), (R, t, piv))
    X = m.gaussians.means.detach().double().numpy()
    assert np.allclose(d.means.double().numpy(), (X - piv) @ R.T + piv + t, atol=1e-6)
    q = d.quats.double()
    assert torch.allclose(q, torch.tensor([math.cos(a / 2), 0, math.sin(a / 2), 0], dtype=torch.float64).expand_as(q),
                          atol=1e-6)


def test_boundary_loss_margin_holds_each_half_d_from_the_plane():
    y = torch.tensor([0.01, 0.02, -0.01, -0.03])
    up = torch.tensor([True, True, False, False])
    assert float(boundary_loss(y, up, 0.0, d=0.005)) == 0.0  # every point at least d away
    # upper 0.01 within 0.015 of the plane: short by 0.005; lower −0.01: short by 0.005
    assert math.isclose(float(boundary_loss(y, up, 0.0, d=0.015)), 0.005 / 2 + 0.005 / 2, rel_tol=1e-6)


def _mapped_upper(m, theta):
    up = m.upper_mask()
    with torch.no_grad():
        return m.deform(theta).means[up]


def test_paper_elements_start_at_identity_and_reach_the_upper_face():
    """θ into MLP_mapping, MLP_gm over (X, S, R), MLP_pm per component: each model starts at the
    canonical Gaussians, and its upper face follows what the option says it reads."""
    X0 = _model(1500).gaussians.means.detach()
    theta = torch.randn(1, 128, generator=torch.Generator().manual_seed(3))
    for cfg in ({"map_theta": True}, {"gm_input": "xsr"}, {"pm_per_component": True},
                {"pm_per_component": True, "mapping_heads": 1}):
        m = _model(1500, global_pose=False, **cfg)
        with torch.no_grad():
            assert torch.allclose(m.deform(theta).means, X0, atol=1e-7), cfg
    # map_theta: with the lower networks at the identity (p_L = 0) the upper face still moves with θ
    m = _model(1500, global_pose=False, map_theta=True, map_norm=False, feat_norm=False)
    _perturb(m)
    with torch.no_grad():
        for mod in (m.mlp_x, m.mlp_s, m.mlp_r):
            mod[-1].weight.zero_()
            mod[-1].bias.zero_()
    a, b = _mapped_upper(m, theta), _mapped_upper(m, 2 * theta)
    assert float((a - b).abs().max()) > 1e-4
    plain = _model(1500, global_pose=False, map_norm=False, feat_norm=False)
    _perturb(plain)
    with torch.no_grad():
        for mod in (plain.mlp_x, plain.mlp_s, plain.mlp_r):
            mod[-1].weight.zero_()
            mod[-1].bias.zero_()
    assert torch.allclose(_mapped_upper(plain, theta), _mapped_upper(plain, 2 * theta), atol=1e-7)
    with pytest.raises(AvatarError, match="theta"):
        m.decode_upper(m.embed(X0[:5]), torch.zeros(5, m.cfg.feat_dim))


def test_gm_over_position_scale_rotation_sees_the_gaussians_shape():
    m = _model(1500, gm_input="xsr")
    _perturb(m)
    E = m.embed(m.gaussians.means.detach())
    G = m.gm_embed(E)
    assert G.shape == (1500, E.shape[1] + 7)
    assert torch.allclose(G[:, E.shape[1]:E.shape[1] + 3], torch.zeros(1500, 3), atol=1e-6)  # equal scales: at the mean
    up = m.upper_mask()
    W0 = m.w_gm(G[up], G[~up])
    with torch.no_grad():  # one lower Gaussian grows: its column of W_gm changes, rows still sum to 1
        m.gaussians.log_scales[torch.nonzero(~up)[0, 0]] += 1.0
    W1 = m.w_gm(m.gm_embed(E)[up], m.gm_embed(E)[~up])
    assert torch.allclose(W1.sum(1), torch.ones(len(W1)), atol=1e-6)
    assert float((W1[:, 0] - W0[:, 0]).detach().abs().max()) > 1e-6
    # a quaternion and its negative are the same rotation: the same embedding
    with torch.no_grad():
        m.gaussians.quats[0] *= -1
    assert torch.allclose(m.gm_embed(E)[0, -4:], G[0, -4:])


def test_pm_per_component_heads_read_only_their_own_component():
    m = _model(1500, global_pose=False, pm_per_component=True, map_norm=False, feat_norm=False, sampling=False)
    _perturb(m)
    F = m.cfg.feat_dim
    E = m.embed(m.gaussians.means.detach())
    up = m.upper_mask()
    pL = torch.randn(int((~up).sum()), 10, generator=torch.Generator().manual_seed(5)) * 0.05
    with torch.no_grad():
        fU = m.map_features(E[up], E[~up], pL)
        assert fU.shape == (int(up.sum()), 3 * F)
        q = pL.clone()
        q[:, 6:] += 0.1  # change ΔR only: the ΔX and ΔS features stay, the ΔR features move
        gU = m.map_features(E[up], E[~up], q)
        assert torch.allclose(fU[:, :2 * F], gU[:, :2 * F]) and not torch.allclose(fU[:, 2 * F:], gU[:, 2 * F:])
        pa, pb = m.decode_upper(E[up], fU), m.decode_upper(E[up], gU)
        assert torch.allclose(pa[:, :6], pb[:, :6]) and not torch.allclose(pa[:, 6:], pb[:, 6:])
    with pytest.raises(AvatarError, match="feature_mapping"):
        HFMConfig(pm_per_component=True, feature_mapping=False)
    with pytest.raises(AvatarError, match="gm_input"):
        HFMConfig(gm_input="xs")
    with pytest.raises(AvatarError, match="split_margin"):
        HFMConfig(split_margin=-1)
