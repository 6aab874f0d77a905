"""The ICT head track: the fit recovers a head it can explain exactly; the table is sound."""
from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.rotations import euler_rotation
from geoface.track.head_track import (TrackSettings, point_bases, fit_head_track, mediapipe_on_ict, view_offsets)


def test_the_mediapipe_to_ict_table_puts_every_point_on_a_face_triangle():
    from geoface.synth.ict import load_ict_model

    tab = mediapipe_on_ict()
    v = load_ict_model().view(("skin", "eyes", "teeth", "mouth"))
    assert tab["vertices"].shape == (468, 3) and tab["model_vertices"] == len(v.neutral)
    assert np.allclose(tab["weights"].sum(1), 1, atol=1e-5) and (tab["weights"] >= 0).all()
    assert np.isin(v.labels[tab["vertices"]], (0, 1)).all()  # the face, not the eyes or teeth
    # MediaPipe's layout: its nose tip (4) in front of its cheeks (234, 454), its forehead (10) above its chin (152)
    mean = point_bases()[0]
    assert mean[4, 2] > mean[234, 2] + 0.02 and mean[4, 2] > mean[454, 2] + 0.02
    assert mean[10, 1] > mean[152, 1] + 0.1
    assert mean[234, 0] * mean[454, 0] < 0  # the cheeks on either side
    assert (tab["confidence"] > 0).all() and (tab["confidence"] <= 1).all()


def _synthetic(T=12, seed=0, f=900.0, size=512):
    """Face-mesh points of a head the model explains exactly: an identity, expressions and a
    turning head, through a camera of focal ``f``."""
    rng = np.random.default_rng(seed)
    mean, Bid, Bex = point_bases()
    ident = rng.normal(0, 1, 10)
    E = np.zeros((T, len(Bex)))
    E[:, 0] = np.linspace(0, 0.8, T)  # a brow goes down
    E[:, 24] = 0.5 * np.sin(np.linspace(0, 3, T)) ** 2  # the jaw opens and closes
    yaw = np.radians(np.linspace(-15, 20, T))
    R = np.stack([np.diag([1.0, -1, -1]) @ euler_rotation(y, 0.1 * y, 0.05) for y in yaw])
    t = np.stack([np.array([0.01 * np.sin(k), -0.01, 0.55]) for k in range(T)])
    X = (mean + np.tensordot(ident, Bid[:10], axes=1))[None] + np.einsum("te,ekd->tkd", E, Bex)
    X = X + view_offsets(R, t, mean.mean(0))
    Xc = np.einsum("tij,tkj->tki", R, X) + t[:, None]
    pts = np.stack([f * Xc[..., 0] / Xc[..., 2] + size / 2, f * Xc[..., 1] / Xc[..., 2] + size / 2], -1)
    return pts, R, t, E, ident


def test_the_fit_recovers_pose_expressions_and_focal_of_a_head_it_can_explain():
    pts, R, t, E, _ = _synthetic()
    s = TrackSettings(n_identity=20, w_smooth=0.0, w_expression=1e-5)
    tr = fit_head_track(pts, (512, 512), focal=900.0, settings=s, quiet=True)
    ang = np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", tr.R, R) - 1) / 2, -1, 1)))
    assert ang.max() < 0.5, ang
    assert np.abs(tr.t - t).max() < 0.01  # m at 0.55 m
    assert np.nanmedian(tr.residual_px) < 0.3
    assert np.corrcoef(tr.expressions[:, 24], E[:, 24])[0, 1] > 0.95  # the jaw
    assert np.corrcoef(tr.expressions[:, 0], E[:, 0])[0, 1] > 0.9  # the brow
    # the focal length found from the perspective alone, starting 25% off
    est = fit_head_track(pts, (512, 512), focal_init=1125.0, settings=s, quiet=True)
    assert abs(est.focal - 900.0) / 900.0 < 0.1, est.focal
    # a frame without a face takes the track through (its neighbours' pose)
    gap = pts.copy()
    gap[5] = np.nan
    tg = fit_head_track(gap, (512, 512), focal=900.0, settings=TrackSettings(n_identity=20), quiet=True)
    assert not tg.found[5] and tg.found.sum() == len(pts) - 1
    a5 = np.degrees(np.arccos(np.clip((np.trace(tg.R[5] @ R[5].T) - 1) / 2, -1, 1)))
    assert a5 < 3.0


def test_held_out_points_are_predicted_by_a_fit_that_did_not_see_them():
    pts, *_ = _synthetic(T=6, seed=1)
    use = np.ones(468, bool)
    use[::5] = False
    tr = fit_head_track(pts, (512, 512), focal=900.0, use=use, settings=TrackSettings(n_identity=20), quiet=True)
    e = np.linalg.norm(tr.points() - pts, axis=-1)
    assert e[:, ~use].mean() < 1.0  # px on a 512 image
    assert np.isnan(tr.residual_px).sum() == 0


def test_a_held_identity_tracks_another_clip_from_the_lower_face_alone():
    """A second clip of the same person seen only below the nose (a headset over the upper face):
    with the identity of the first clip's track held, its head poses come back within half a
    degree; fitting the identity again from the lower face alone leaves them degrees off."""
    pts, *_ = _synthetic(T=12, seed=0)
    s = TrackSettings(n_identity=20, w_smooth=0.0, w_expression=1e-5)
    first = fit_head_track(pts, (512, 512), focal=900.0, settings=s, quiet=True)
    pts2, R2, t2, _, _ = _synthetic(T=8, seed=0)  # the same person, another motion
    mean = point_bases()[0]
    lower = mean[:, 1] < mean[1, 1] - 0.01  # below the nose tip

    def degrees(tr):
        return np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", tr.R, R2) - 1) / 2, -1, 1)))

    held = fit_head_track(pts2, (512, 512), focal=900.0, use=lower, identity=first.identity, settings=s, quiet=True)
    free = fit_head_track(pts2, (512, 512), focal=900.0, use=lower, settings=s, quiet=True)
    assert np.array_equal(held.identity, first.identity)
    assert degrees(held).max() < 0.5 and np.abs(held.t - t2).max() < 0.003, (degrees(held), held.t - t2)
    assert degrees(free).mean() > 3 * degrees(held).mean()
    with pytest.raises(GeofaceError, match="identity"):
        fit_head_track(pts2, (512, 512), focal=900.0, identity=np.full(3, np.nan), quiet=True)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((3, 68, 2)), "468"),
    (np.full((3, 468, 2), np.nan), "no face"),
])
def test_bad_points_are_one_line_errors(bad, match):
    with pytest.raises(GeofaceError, match=match):
        fit_head_track(bad, (256, 256), quiet=True)
    with pytest.raises(GeofaceError, match="focal"):
        fit_head_track(_synthetic(T=2)[0], (512, 512), focal=-1.0, quiet=True)
