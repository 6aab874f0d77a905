"""Facial regions on the ICT-FaceKit UV layout and the regional skin drawn with them."""
from __future__ import annotations

import numpy as np
import pytest

from geoface.skin import SkinError

from geoface.skin.regions import REGION_NAMES, ict_uv_regions, landmark_uv
from geoface.skin.render import skin_maps

R = 192


@pytest.fixture(scope="module")
def head():
    from geoface.synth.ict import load_ict_model
    m = load_ict_model()
    return m.head(identity=np.zeros(m.n_identities))


@pytest.fixture(scope="module")
def regions(head):
    return ict_uv_regions(R, head)


def at(mask, uv):
    """The mask's value at UV point(s) (row 0 = v 1)."""
    uv = np.atleast_2d(uv)
    r = np.clip(((1 - uv[:, 1]) * R).astype(int), 0, R - 1)
    c = np.clip((uv[:, 0] * R).astype(int), 0, R - 1)
    return mask[r, c]


def test_regions_sit_where_the_landmarks_say(head, regions):
    L = landmark_uv(head)
    assert set(regions) == set(REGION_NAMES)
    assert all(m.shape == (R, R) and m.dtype == np.float32 and 0 <= m.min() and m.max() <= 1 for m in regions.values())
    lip_mid = 0.5 * (L[51] + L[62])  # between the upper lip's top and the mouth line: on the lip
    assert at(regions["lips"], lip_mid) > 0.5
    assert (at(regions["brows"], L[[19, 24]]) > 0.5).all()
    assert (at(regions["nose"], L[[30, 33]]) > 0.5).all()
    eye_w = np.linalg.norm(L[39] - L[36])
    assert (at(regions["eyelids"], L[[37, 44]] + [0.0, 0.15 * eye_w]) > 0.5).all()  # just above the lid line
    assert (at(regions["cheeks"], 0.5 * (L[[41, 46]] + L[[48, 54]])) > 0.3).all()
    above = L[27] + np.array([0.0, 1.8 * (L[19:25, 1].max() - L[27, 1]) + 0.05])
    assert at(regions["forehead"], above) > 0.5
    assert at(regions["beard"], 0.5 * (L[8] + L[57])) > 0.5  # the chin
    # regions stay apart: no lips on the nose tip, no beard on the lips, no forehead on the nose
    assert at(regions["lips"], L[30]) < 0.05 and at(regions["beard"], lip_mid) < 0.1
    assert at(regions["forehead"], L[30]) == 0 and at(regions["beard"], L[30]) < 0.05
    # the eye openings are not eyelid
    assert (at(regions["eyelids"], np.stack([L[36:42].mean(0), L[42:48].mean(0)])) < 0.5).all()
    # the face covers the landmarks; areas are plausible shares of the tile
    assert (at(regions["face"], L) > 0.5).all()
    assert 0.005 < regions["lips"].mean() < 0.05 and 0.05 < regions["forehead"].mean() < 0.25
    with pytest.raises(SkinError, match="res"):
        ict_uv_regions(8, head)


def _mean(x, m):
    w = (m > 0.9).astype(np.float64)
    return (x * (w[..., None] if x.ndim == 3 else w)).sum(axis=(0, 1)) / w.sum()


def test_regional_skin_statistics(regions):
    m = skin_maps(R, seed=3, regions=regions, tone=1, redness=0.3, freckles=0.0)
    plain = skin_maps(R, seed=3, tone=1, redness=0.3, freckles=0.0)
    a, s, h = m.albedo, m.specular[..., 0], m.height
    # lips: redder than the cheeks and shinier; without regions nothing differs there
    lr, cr = _mean(a, regions["lips"]), _mean(a, regions["cheeks"])
    assert lr[0] / lr[1] > 1.25 * cr[0] / cr[1]
    pr = _mean(plain.albedo, regions["lips"]), _mean(plain.albedo, regions["cheeks"])
    assert abs(pr[0][0] / pr[0][1] - pr[1][0] / pr[1][1]) < 0.05
    assert _mean(s, regions["nose"]) > _mean(s, regions["cheeks"]) + 0.1
    # brows: darker than the forehead
    assert _mean(a, regions["brows"]).sum() < 0.85 * _mean(a, regions["forehead"]).sum()
    # pores are pits: more and larger on the nose lower its mean height against the same skin
    # without regions (by about 3e-5 UV units), none on the lips raise it (by about 2e-5)
    assert _mean(h - plain.height, regions["nose"]) < -1.5e-5
    assert _mean(h - plain.height, regions["lips"]) > 0.8e-5
    # eyelid folds run across (height changes up the face), lip lines run up (changes across)
    du, dv = np.abs(np.diff(h, axis=1))[:-1], np.abs(np.diff(h, axis=0))[:, :-1]
    lids, lips = regions["eyelids"][:-1, :-1], regions["lips"][:-1, :-1]
    assert _mean(dv, lids) > 1.5 * _mean(du, lids) and _mean(du, lips) > 1.5 * _mean(dv, lips)
    # the same seed without regions is the old skin: same tone and pores away from the face
    assert np.allclose(plain.albedo, skin_maps(R, seed=3, tone=1, redness=0.3, freckles=0.0).albedo)


def test_stubble_only_in_the_beard(regions):
    # a seed with stubble and one without (a trait drawn from the seed, as skin_maps draws it)
    from geoface.texture import synth as skin_synth
    with_st = [sd for sd in range(40) if _has_stubble(sd)]
    without = [sd for sd in range(40) if not _has_stubble(sd)]
    assert with_st and without
    sd = with_st[0]
    m = skin_synth.skin_maps(R, seed=sd, regions=regions, tone=0)
    no_beard = {k: (v if k != "beard" else np.zeros_like(v)) for k, v in regions.items()}
    m0 = skin_synth.skin_maps(R, seed=sd, regions=no_beard, tone=0)
    diff = np.abs(m.albedo - m0.albedo).sum(-1)
    assert _mean(diff, regions["beard"]) > 0.02 and _mean(diff, regions["forehead"]) == 0


def _has_stubble(seed: int) -> bool:
    t = np.random.default_rng([seed, 99])
    t.uniform(0.1, 1.0)
    return bool(t.uniform(0.2, 1.0) if t.random() < 0.4 else 0.0)


def test_regions_shape_mismatch_is_an_error(regions):
    with pytest.raises(SkinError, match="region"):
        skin_maps(R // 2, seed=0, regions=regions)
