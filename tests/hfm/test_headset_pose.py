"""Head poses corrected by the headset's silhouette (geoface.hfm.headset_pose) on an analytic rig:
a box rigid with the head, rasterised as its projected convex hull, and landmark poses that an
expression shifts."""
import numpy as np
import pytest

from geoface.errors import AvatarError
from geoface.avatar.head_pose import project_points, rodrigues
from geoface.hfm.headset_pose import fit_headset, headset_centroids, headset_components, headset_poses

RES = 256


def _camera():
    from geoface.camera import look_at

    return look_at([0.0, 0.0, 0.45], [0.0, 0.0, 0.0], width=RES, height=RES, fov_y_deg=36.0)


def _box():
    """The headset: a 19 x 10.5 x 9 cm box in front of the eyes (head frame, metres)."""
    x, y, z = np.meshgrid([-0.095, 0.095], [-0.06, 0.045], [-0.02, 0.07], indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], 1)


def _mask(cam, R, t, piv, box):
    from scipy.spatial import ConvexHull
    from skimage.draw import polygon

    uv = project_points(cam, (box - piv) @ R.T + piv + t)
    h = uv[ConvexHull(uv).vertices]
    m = np.zeros((RES, RES), bool)
    rr, cc = polygon(h[:, 1] - 0.5, h[:, 0] - 0.5, m.shape)  # pixel centres at +0.5
    m[rr, cc] = True
    return m


def _rig(T=60, seed=0):
    """True poses of a moving head, the headset masks, lower-face landmark points, and poses that
    an expression (score ramping 0 → 1 over the video) puts 1.5 mm too high and 0.3° pitched."""
    rng = np.random.default_rng(seed)
    cam = _camera()
    piv = np.array([0.0, -0.05, 0.0])
    s = np.linspace(0.0, 1.0, T)
    ang = np.stack([np.radians(6) * np.sin(np.linspace(0, 3, T)), np.radians(2) * np.sin(np.linspace(1, 5, T)),
                    np.radians(2) * np.cos(np.linspace(0, 4, T))], 1)
    R = np.stack([rodrigues(a) for a in ang])
    t = 0.004 * np.stack([np.sin(np.linspace(0, 2, T)), np.cos(np.linspace(0, 3, T)), np.sin(np.linspace(2, 4, T))], 1)
    box = _box()
    masks = np.stack([_mask(cam, R[f], t[f], piv, box) for f in range(T)])
    P = np.c_[rng.uniform(-0.05, 0.05, 10), rng.uniform(-0.08, -0.02, 10), rng.uniform(0.0, 0.06, 10)]
    Rb = np.stack([R[f] @ rodrigues([np.radians(0.3) * s[f], 0, 0]) for f in range(T)])
    tb = t + np.outer(s, [0.0, 0.0015, 0.0])
    Z = np.c_[s, 0.3 * rng.standard_normal(T)]  # the expression's score (zero where it does nothing) and an unrelated one
    return cam, R, t, piv, masks, P, Rb, tb, Z


def _err_px(cam, R, t, Ra, ta, piv, X):
    """Mean image distance of head points ``X`` under two sets of poses."""
    return float(np.mean([np.linalg.norm(project_points(cam, (X - piv) @ Ra[f].T + piv + ta[f])
                                         - project_points(cam, (X - piv) @ R[f].T + piv + t[f]), axis=1).mean()
                          for f in range(len(R))]))


INIT = np.array([0.0, 0.0, 0.07])  # a head point near the headset: where its front face is


def test_headset_centroids_of_a_drawn_box_and_what_is_left_out():
    cam, R, t, piv, masks, *_ = _rig(T=4)
    c = headset_centroids(masks)
    assert np.isfinite(c).all()
    # the silhouette's centroid lies near the projection of the box's front face centre
    front = project_points(cam, ((_box()[1::2].mean(0) - piv) @ R[0].T + piv + t[0])[None])[0]
    assert np.linalg.norm(c[0] - front) < 1.0
    m = masks.copy()
    m[1, :, 0] = True      # touches the border: cut off
    m[2] = False
    m[2, 10:13, 10:13] = True  # too small
    c2 = headset_centroids(m)
    assert np.isnan(c2[1]).all() and np.isnan(c2[2]).all() and np.allclose(c2[[0, 3]], c[[0, 3]])
    with pytest.raises(AvatarError, match=r"\[T, H, W\]"):
        headset_centroids(masks[0])
    assert headset_components(50, 8) == 8 and headset_components(30, 8) == 4 and headset_components(17, 8) == 0


def test_the_headset_model_follows_the_silhouette_in_the_true_poses():
    """A point and a view map explain the box's centroid to a tenth of a pixel (at 256 px) through
    the head's motion; a point alone does not (the nearer side of a turned box covers more)."""
    cam, R, t, piv, masks, *_ = _rig()
    cen = headset_centroids(masks)
    h = fit_headset(cam, R, t, piv, cen, INIT)
    assert h["rms_px"] < 0.12 and h["expression"] is None
    assert np.linalg.norm(h["anchor"][:2] - _box()[1::2].mean(0)[:2]) < 0.003  # on the box's axis
    assert fit_headset(cam, R, t, piv, cen, INIT, view=False)["rms_px"] > 2 * h["rms_px"]
    with pytest.raises(AvatarError, match="usable centroids"):
        fit_headset(cam, R[:5], t[:5], piv, cen[:5], INIT)


def test_headset_corrects_what_an_unseen_expression_did_to_the_landmark_poses():
    centre = _box()[1::2].mean(0, keepdims=True)
    for seed in (0, 1):
        cam, R, t, piv, masks, P, Rb, tb, Z = _rig(seed=seed)
        before = _err_px(cam, R, t, Rb, tb, piv, centre)
        assert before > 0.5
        R2, t2, info = headset_poses(cam, Rb, tb, piv, P, headset_centroids(masks), INIT, Z)
        after = _err_px(cam, R, t, R2, t2, piv, centre)
        assert after < 0.7 * before, (seed, before, after)  # 0.58 -> 0.34-0.37 px at the default ridge
        assert _err_px(cam, R, t, R2, t2, piv, _box()[1::2]) < _err_px(cam, R, t, Rb, tb, piv, _box()[1::2])
        assert info["headset_frames"] == len(R) and info["headset_shift_px_max"] > 0.3
        # right poses stay nearly right: what the expression map takes up from noise is small
        R3, t3, _ = headset_poses(cam, R, t, piv, P, headset_centroids(masks), INIT, Z)
        assert _err_px(cam, R, t, R3, t3, piv, _box()[1::2]) < 0.12
    with pytest.raises(AvatarError, match="too few"):
        headset_poses(cam, R[:17], t[:17], piv, P, headset_centroids(masks[:17]), INIT, Z[:17])
