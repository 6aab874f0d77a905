"""Head poses from landmarks (PnP), the ICT-FaceKit HMD captures, and HFM-GS without a pose file."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from geoface.errors import CaptureError
import torch

from geoface.camera import look_at
from geoface.errors import AvatarError
from geoface.avatar.head_pose import (landmarks_on_mesh, poses_from_landmarks, rodrigues, rotation_vector, solve_poses,
                                     triangulate)
from geoface.hfm.data import LOWER_FACE_LANDMARKS, load_video
from geoface.avatar.capture import IBUG68_LOWER, IBUG68_NAMES


def _angle_deg(A, B) -> float:
    return float(np.degrees(np.linalg.norm(rotation_vector(A.T @ B))))


def test_rodrigues_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = rng.normal(0, 0.8, 3)
        R = rodrigues(w)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1)
        assert np.allclose(rotation_vector(R), w, atol=1e-9)


def test_the_pose_fits_jacobian_is_the_derivative_of_its_residuals():
    """solve_poses fits with an exact Jacobian (the rotation vector's derivative, Gallego & Yezzi):
    it matches central differences of the residuals to 1e-6 of its size, at a large rotation, a
    tiny one and none, under an oblique camera and uneven weights."""
    from geoface.avatar.head_pose import _pose_jacobian, project_points

    rng = np.random.default_rng(3)
    cam = look_at([0.1, 0.05, 0.5], [0, 0, 0], width=256, height=256, fov_y_deg=36)
    Q = rng.normal(0, 1, (15, 3)) * [0.05, 0.06, 0.03]
    piv = np.array([0.0, -0.1, 0.02])
    wk = rng.uniform(0.5, 2.0, (15, 1))

    def resid(x):
        return ((project_points(cam, Q @ rodrigues(x[:3]).T + piv + x[3:])) * wk).ravel()

    for rot in (rng.normal(0, 1, 3), rng.normal(0, 1, 3) * 1e-9, np.zeros(3)):
        x = np.r_[rot, rng.normal(0, 0.01, 3)]
        J = _pose_jacobian(cam, Q, piv, x, wk)
        h = 1e-6
        fd = np.stack([(resid(x + h * e) - resid(x - h * e)) / (2 * h) for e in np.eye(6)], 1)
        assert J.shape == (30, 6) and np.abs(J - fd).max() < 1e-6 * np.abs(fd).max(), np.abs(J - fd).max()


def test_triangulation_recovers_points_a_ray_cast_misplaced():
    """Points started 1–2 cm off along the view (a jaw outline's ray meeting the cheek) are put
    back within 2.5 mm (1.2 mm on average; depth is what ±10° of parallax resolves least) from 40 frames of ±10° head motion and 0.5 px noise — a quarter of the
    frames with the point moved 8 px (an expression), which the robust loss ignores."""
    rng = np.random.default_rng(4)
    cam = look_at([0, 0, 0.45], [0, 0, 0], width=256, height=256, fov_y_deg=36)
    P = rng.normal(0, 1, (6, 3)) * [0.06, 0.05, 0.02] + [0, 0, 0.03]
    piv = np.array([0.0, -0.1, 0.0])
    T = 40
    R = np.stack([rodrigues(rng.normal(0, 1, 3) * np.radians(6)) for _ in range(T)])
    t = rng.normal(0, 0.004, (T, 3))
    obs = np.stack([cam.project((P - piv) @ R[f].T + piv + t[f])[0] for f in range(T)])
    obs += rng.normal(0, 0.5, obs.shape)
    obs[: T // 4, :, 1] += 8.0
    init = P + rng.choice([-1, 1], (6, 1)) * rng.uniform(0.01, 0.02, (6, 1)) * [0, 0, 1]
    X = triangulate(cam, {"R": R, "t": t, "pivot": piv}, obs, init)
    err = np.linalg.norm(X - P, axis=1)
    assert err.max() < 2.5e-3 and err.mean() < 1.2e-3
    assert np.linalg.norm(init - P, axis=1).min() > 9e-3
    # a point seen in one frame only keeps its start
    lone = obs.copy()
    lone[1:, 0] = np.nan
    assert np.array_equal(triangulate(cam, {"R": R, "t": t, "pivot": piv}, lone, init)[0], init[0])


def test_pnp_recovers_poses_through_noise_and_moving_points():
    """20 head-sized points, poses of up to 15° and 1 cm, 0.5 px landmark noise, and 3 points
    that an expression moves by 6–15 px: the robust fit recovers the pose about as well as the
    noise allows (mean 0.5°, worst 0.85°, 1 mm here); a plain least-squares fit (a huge loss
    scale) is pulled off by the moved points."""
    rng = np.random.default_rng(1)
    cam = look_at([0, 0, 0.45], [0, 0, 0], width=256, height=256, fov_y_deg=36)
    P = rng.normal(0, 1, (20, 3)) * [0.05, 0.06, 0.03] + [0, 0, 0.05]
    piv = np.array([0.0, -0.1, 0.0])
    T = 12
    Rs = [rodrigues(rng.normal(0, 1, 3) * np.radians(8)) for _ in range(T)]
    ts = rng.normal(0, 0.005, (T, 3))
    obs = np.stack([cam.project((P - piv) @ R.T + piv + t)[0] for R, t in zip(Rs, ts)])
    obs += rng.normal(0, 0.5, obs.shape)
    obs[:, :3] += rng.uniform(6, 15, (T, 3, 2)) * rng.choice([-1, 1], (T, 3, 2))
    fit = solve_poses(cam, P, obs, piv)
    err = [_angle_deg(Rs[f], fit["R"][f]) for f in range(T)]
    assert np.mean(err) < 0.65 and max(err) < 1.2
    assert max(np.linalg.norm(fit["t"] - ts, axis=1)) < 1.5e-3
    assert (fit["inliers"] == 17).all() and np.median(fit["rms_px"]) < 1.0
    plain = solve_poses(cam, P, obs, piv, scale_px=1e6)
    assert np.mean([_angle_deg(Rs[f], plain["R"][f]) for f in range(T)]) > 2 * np.mean(err)
    with pytest.raises(AvatarError, match="need 4"):
        solve_poses(cam, P[:3], obs[:, :3], piv)


def test_landmarks_land_on_the_mesh_sub_pixel():
    """A tilted plane: the rays through projected surface points meet it at those points."""
    cam = look_at([0, 0, 1.0], [0, 0, 0], width=64, height=64, fov_y_deg=40)
    g = np.linspace(-0.3, 0.3, 11)
    X, Y = np.meshgrid(g, g)
    V = np.c_[X.ravel(), Y.ravel(), 0.3 * X.ravel() - 0.1 * Y.ravel()]
    idx = np.arange(121).reshape(11, 11)
    F = np.r_[np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()],
              np.c_[idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]]
    Q = np.array([[0.013, 0.021, 0.0], [-0.1, 0.07, 0.0], [0.15, -0.12, 0.0]])
    Q[:, 2] = 0.3 * Q[:, 0] - 0.1 * Q[:, 1]
    uv = cam.project(Q)[0]
    pts, ok = landmarks_on_mesh(V, F, cam, np.r_[uv, [[500.0, 3.0]]])
    assert ok.tolist() == [True, True, True, False]
    assert np.allclose(pts[:3], Q, atol=1e-9)


@pytest.fixture(scope="module")
def ict_capture(tmp_path_factory):
    from geoface.hfm.ict import make_ict_hmd

    out = tmp_path_factory.mktemp("ict_hmd")
    return make_ict_hmd(out, frames=12, usage_frames=3, res=64, seed=5, gaussians=800, map_res=128, supersample=1,
                        quiet=True)


def test_ict_capture_folders(ict_capture):
    reg, use = ict_capture
    v = load_video(reg, need_mesh=True)
    u = load_video(use)
    assert len(v) == 12 and len(u) == 3 and v.names == list(IBUG68_NAMES)
    assert u.names == [IBUG68_NAMES[i] for i in IBUG68_LOWER] and all(n in u.names for n in LOWER_FACE_LANDMARKS)
    assert v.poses is not None and u.poses is not None and u.gt_static_upper is not None
    # frame 0 is the rest pose (head.ply); the head then moves
    assert np.allclose(v.poses[0][0], np.eye(3)) and np.allclose(v.poses[1][0], 0)
    assert max(_angle_deg(np.eye(3), R) for R in v.poses[0]) > 0.5
    # the headset hides the upper face: there the frame differs from the truth, below it not
    m = u.hmd_masks[0]
    assert 0.05 < m.mean() < 0.5
    diff = np.abs(u.frames[0] - u.gt[0]).max(-1)
    assert diff[m].mean() > 0.05 and np.median(diff[~m & u.masks[0]]) < 0.02
    meta = json.loads((reg / "meta.json").read_text())
    assert meta["source"] == "ICT-FaceKit" and meta["frames"][0]["expression"] == {}
    # registration and usage are different sequences, each with talking (the jaw moves)
    jaw = [[f["expression"].get("jawOpen", 0) for f in json.loads((d / "meta.json").read_text())["frames"]] for d in (reg, use)]
    assert max(jaw[0]) > 0.05


def test_range_of_motion_opens_the_registration_with_each_emotion_at_full_weight():
    """``rom`` seconds: surprise, smile and anger each reach weight 1 in their own third (one at a
    time, no speech), the free sequence after it is the one drawn without it, and a range of
    motion longer than the video is refused."""
    from geoface.hfm.ict import make_ict_hmd
    from geoface.avatar.ict import arkit_curves

    fps, T = 25.0, 200
    free, rom = (arkit_curves(T, np.random.default_rng(3), fps=fps, rom=r) for r in (0.0, 3.0))
    w = lambda c, k: np.array([f[k] for f in c])  # noqa: E731
    t = np.arange(T) / fps
    for j, k in enumerate(("browOuterUp_L", "mouthSmile_L", "browDown_L")):
        part = (t >= 0.2 + j) & (t < 0.2 + j + 1)
        assert w(rom, k)[part].max() > 0.999 and w(rom, k)[(t >= 0.2) & (t < 3.2) & ~part].max() < 0.01
    assert w(rom, "mouthFunnel")[t < 3.2].max() == 0 and w(rom, "mouthClose")[t < 3.2].max() == 0
    after = t >= 3.7
    for k in free[0]:
        assert np.array_equal(w(free, k)[after], w(rom, k)[after]), k
    with pytest.raises(AvatarError, match="range of motion"):
        make_ict_hmd("unused", frames=20, rom=1.0, quiet=True)


def test_lit_frames_change_with_pose_under_fixed_lights(ict_capture):
    """The lights stay in the world: the same person in two poses is not just a moved image —
    shading changes (a frame's mean brightness differs beyond what a small move explains)."""
    from geoface.texture.synth import random_lights

    d = random_lights(np.random.default_rng(0), 3)[0]
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    reg, _ = ict_capture
    v = load_video(reg)
    lum = [float(f[m].mean()) for f, m in zip(v.frames, v.masks)]
    assert np.ptp(lum) > 0.003


def test_poses_from_the_landmarks_of_an_ict_capture(ict_capture):
    """PnP on the 68 landmarks of the rendered person (rigid subset) gives the true head poses
    within 1°, 2 mm across the view and 6 mm along it (64² frames, head.ply decimated to 800
    vertices), although expressions move the face."""
    from geoface.mesh.io import load_mesh

    reg, _ = ict_capture
    v = load_video(reg, need_mesh=True)
    m = load_mesh(v.mesh_path)
    fit = poses_from_landmarks(v, m.V, m.F)
    R, t, piv = v.poses
    p = fit["pivot"]
    for f in range(len(v)):
        assert _angle_deg(R[f], fit["R"][f]) < 1.0
        t_true = (piv - R[f] @ piv + t[f]) - (p - R[f] @ p)
        e = fit["t"][f] - t_true  # the camera looks along −z
        assert np.linalg.norm(e[:2]) < 2e-3 and abs(e[2]) < 6e-3
    assert np.median(fit["rms_px"]) < 0.5 and len(fit["names"]) >= 12


def _lower_rig(rng):
    """A camera, 12 "rigid" points (``r*``) and 16 mouth points (``m*``) of a lower face, and a pivot."""
    cam = look_at([0, 0, 0.5], [0, 0, 0], width=256, height=256, fov_y_deg=30)
    fit_names = [f"r{i}" for i in range(12)]
    P = np.r_[rng.normal(0, 1, (12, 3)) * [0.06, 0.03, 0.02], rng.normal(0, 1, (16, 3)) * [0.03, 0.01, 0.01] - [0, 0.05, 0]]
    return cam, fit_names, fit_names + [f"m{i}" for i in range(16)], P, np.array([0.0, 0.0, -0.05])


def test_lower_pose_calibration_undoes_the_tilt_expressions_give_the_lower_landmarks():
    """Two expressions move 4 "rigid" nose points up and forward (a sneer) and the mouth points
    with them (and a third moves the mouth alone): the pose fitted to the 12 lower points then tilts
    by ~0.5° with the expression. Calibrated on 150 registration frames whose poses are known, the
    tilt on 40 held-out frames of other poses and stronger expressions falls to under a third (to
    0.12°; the robust fit makes the tilt nonlinear in the expression), and a calibration to poses
    that are the lower fit's own changes nothing."""
    from geoface.avatar.head_pose import apply_lower_calibration, calibrate_lower_poses

    rng = np.random.default_rng(3)
    cam, fit_names, names, P, piv = _lower_rig(rng)
    modes = np.zeros((3, 28, 3))
    modes[0, :4] = [0, 0.004, 0.002]  # sneer: the nose points lift, the upper lip with them
    modes[0, 12:20] = [0, 0.003, 0]
    modes[1, :4] = [0, -0.002, 0.003]  # smile
    modes[1, 12:28] = rng.normal(0, 0.004, (16, 3))
    modes[2, 20:28] = [0, -0.008, 0]  # jaw

    def frames(T, strength):
        R = np.stack([rodrigues(rng.normal(0, 1, 3) * np.radians(4)) for _ in range(T)])
        t = rng.normal(0, 0.004, (T, 3))
        c = rng.uniform(0, strength, (T, 3))
        obs = np.stack([cam.project((P + np.tensordot(c[f], modes, 1) - piv) @ R[f].T + piv + t[f])[0] for f in range(T)])
        return R, t, obs + rng.normal(0, 0.05, obs.shape)

    R, t, obs = frames(150, 1.0)
    cal = calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), fit_names=fit_names, feature_names=names[12:],
                                components=12, ridge=1e-4)
    R2, t2, obs2 = frames(40, 1.5)
    low = solve_poses(cam, P[:12], obs2[:, :12], piv)
    before = [_angle_deg(R2[f], low["R"][f]) for f in range(40)]
    Rc, tc = apply_lower_calibration(cal, cam, dict(zip(names, P)), obs2, names, low["R"], low["t"], piv)
    after = [_angle_deg(R2[f], Rc[f]) for f in range(40)]
    assert np.mean(before) > 0.3 and np.mean(after) < 0.3 * np.mean(before)
    assert np.mean(np.linalg.norm(tc - t2, axis=1)) < 0.5 * np.mean(np.linalg.norm(low["t"] - t2, axis=1))
    # nothing to learn when the reference poses are the lower fit's own
    own = solve_poses(cam, P[:12], obs[:, :12], piv)
    same = calibrate_lower_poses(cam, names, P, obs, names, (own["R"], own["t"], piv), fit_names=fit_names,
                                 feature_names=names[12:], components=12, ridge=1e-4)
    R3, t3 = apply_lower_calibration(same, cam, dict(zip(names, P)), obs2, names, low["R"], low["t"], piv)
    assert max(_angle_deg(a, b) for a, b in zip(R3, low["R"])) < 0.02
    assert apply_lower_calibration(cal, cam, dict(zip(names[:-1], P)), obs2, names, low["R"], low["t"], piv) is None
    assert calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), fit_names=fit_names[:3]) is None


def test_rigidity_weights_favour_the_points_that_stay_and_the_weighted_fit_tilts_less():
    """On a rig where expressions move 4 of 12 "rigid" points (nose wings: a sneer), the weights
    learned from registration frames put the moving points at under a tenth of the still ones, the
    pose weighted by them tilts under half as much with the expression as the equal-weight fit on
    held-out frames, a weighted calibration saves them (``fit_weights``) and bad weights are refused."""
    from geoface.avatar.head_pose import calibrate_lower_poses, rigidity_weights

    rng = np.random.default_rng(5)
    cam = look_at([0, 0, 0.5], [0, 0, 0], width=256, height=256, fov_y_deg=30)
    P = rng.normal(0, 1, (12, 3)) * [0.06, 0.03, 0.02]
    piv = np.array([0.0, 0.0, -0.05])
    mode = np.zeros((12, 3))
    mode[:4] = [0, 0.004, 0.002]

    def frames(T, strength):
        R = np.stack([rodrigues(rng.normal(0, 1, 3) * np.radians(4)) for _ in range(T)])
        t = rng.normal(0, 0.004, (T, 3))
        c = rng.uniform(0, strength, T)
        obs = np.stack([cam.project((P + c[f] * mode - piv) @ R[f].T + piv + t[f])[0] for f in range(T)])
        return R, t, obs + rng.normal(0, 0.05, obs.shape)

    R, t, obs = frames(150, 1.0)
    w = rigidity_weights(cam, R, t, piv, P, obs)
    assert w.shape == (12,) and abs(w.mean() - 1) < 1e-9 and w[:4].max() < 0.1 * w[4:].min()
    R2, t2, obs2 = frames(40, 1.5)
    plain, weighted = solve_poses(cam, P, obs2, piv), solve_poses(cam, P, obs2, piv, weights=w)
    tilt = [np.mean([_angle_deg(R2[f], fit["R"][f]) for f in range(40)]) for fit in (plain, weighted)]
    assert tilt[0] > 0.1 and tilt[1] < 0.5 * tilt[0]
    names = [f"r{i}" for i in range(12)]
    cal = calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), fit_names=names, feature_names=names,
                                components=4, weighted=True)
    assert np.allclose(cal["fit_weights"], w)
    assert "fit_weights" not in calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), fit_names=names,
                                                      feature_names=names, components=4)
    for bad in (w[:5], -w, w * np.nan):
        with pytest.raises(AvatarError, match="weights"):
            solve_poses(cam, P, obs2[:2], piv, weights=bad)


def test_poses_fitted_to_the_landmarks_below_a_headset(ict_capture):
    """``fit_names``: the poses fitted to the 12 lower landmarks (nose base, jaw ends) that a usage
    video keeps, the head placed (and the jaw outline triangulated) as with the rigid set: same
    pivot and 3D points, poses within 1.5° and 3 mm across the view of the truth, and they differ
    from the rigid-set fit (other points)."""
    from geoface.mesh.io import load_mesh
    from geoface.avatar.head_pose import LOWER_RIGID_NAMES

    reg, _ = ict_capture
    v = load_video(reg, need_mesh=True)
    m = load_mesh(v.mesh_path)
    rigid = poses_from_landmarks(v, m.V, m.F)
    low = poses_from_landmarks(v, m.V, m.F, fit_names=LOWER_RIGID_NAMES)
    assert sorted(low["names"]) == sorted(n for n in LOWER_RIGID_NAMES if n in rigid["all_names"])
    assert np.allclose(low["pivot"], rigid["pivot"]) and np.allclose(low["all_points3d"], rigid["all_points3d"])
    R, t, piv = v.poses
    p = low["pivot"]
    for f in range(len(v)):
        assert _angle_deg(R[f], low["R"][f]) < 1.5
        e = low["t"][f] - ((piv - R[f] @ piv + t[f]) - (p - R[f] @ p))
        assert np.linalg.norm(e[:2]) < 3e-3
    assert max(_angle_deg(a, b) for a, b in zip(low["R"], rigid["R"])) > 1e-3
    with pytest.raises(AvatarError, match="need 4"):
        poses_from_landmarks(v, m.V, m.F, fit_names=("nose_tip", "jaw_00"))


def test_stable_registration_landmarks_ignore_the_points_expressions_move(ict_capture):
    """``registration_poses(fit="stable")`` places the head (and triangulates the jaw line) with
    :data:`STABLE_NAMES` alone and fits the poses to them, within 1° and 2 mm across the view of the
    truth; when a sneer-like motion lifts the nose wings, the top of the nose ridge and the jaw
    line's third points by 1.5 px the rigid-set poses tilt with it and the stable-set poses do not move."""
    from dataclasses import replace

    from geoface.mesh.io import load_mesh
    from geoface.avatar.head_pose import STABLE_NAMES
    from geoface.hfm.train import registration_poses

    reg, _ = ict_capture
    v = load_video(reg, need_mesh=True)
    m = load_mesh(v.mesh_path)
    truth = v.poses
    info = registration_poses(replace(v), "landmarks", mesh=m, fit="stable")
    assert info["pose_landmarks"] == len([n for n in STABLE_NAMES if n in info["landmarks3d"]["names"]]) >= 10
    moved = [v.names.index(n) for n in ("nose_base_0", "nose_base_1", "nose_base_3", "nose_base_4", "nose_bridge_0",
                                        "jaw_02", "jaw_14")]
    lm = v.landmarks.copy()
    lm[:, moved, 1] -= 1.5 * np.linspace(0, 1, len(v))[:, None]  # up in the image, growing over the video
    fits = {}
    for fit in ("stable", "rigid"):
        for name, marks in (("still", v.landmarks), ("sneer", lm)):
            w = replace(v, landmarks=marks, poses=None)
            registration_poses(w, "landmarks", mesh=m, fit=fit)
            fits[fit, name] = w.poses
    R, t, piv = truth
    Rs, ts, p = fits["stable", "still"]
    for f in range(len(v)):
        assert _angle_deg(R[f], Rs[f]) < 1.0
        assert np.linalg.norm((ts[f] - ((piv - R[f] @ piv + t[f]) - (p - R[f] @ p)))[:2]) < 2e-3
    tilt = {k: max(_angle_deg(a, b) for a, b in zip(fits[k, "still"][0], fits[k, "sneer"][0])) for k in ("stable", "rigid")}
    assert tilt["rigid"] > 0.1 and tilt["stable"] < 0.02 * tilt["rigid"]


def test_hfm_without_a_pose_file_learns_the_pose_from_the_crop(ict_capture, tmp_path):
    """Registered with poses from the landmarks, the model reads each frame's pose from its
    lower-face crop: after a short training, closer to the registration poses than the rest pose is."""
    from geoface.hfm import HFMConfig, evaluate_hmd, load_hfm, train_hfm
    from geoface.hfm.usage import usage_poses

    reg, use = ict_capture
    cfg = HFMConfig(iters=50, warmup=0.1, densify=False, seed=0, lr_nets=1e-3, n_keys=128, crop=64)
    info = train_hfm(reg, tmp_path / "m", cfg, progress=False, log=None, poses="landmarks")
    assert info["poses"] == "landmarks" and info["pose_fit_rms_px"] < 0.5
    assert any("pose" in r for r in info["history"])
    m = load_hfm(tmp_path / "m")
    # what the pose MLP reads from the registration crops is closer to the fitted poses than the rest pose is
    from geoface.mesh.io import load_mesh

    v = load_video(reg, need_mesh=True)
    mesh = load_mesh(v.mesh_path)
    fit = poses_from_landmarks(v, mesh.V, mesh.F)
    target = np.stack([m.pose_params_of(fit["R"][f], fit["t"][f], fit["pivot"]) for f in range(len(v))])
    with torch.no_grad():
        pred = m.head_pose_params(m.encoder(torch.tensor(v.crops(cfg.crop)), torch.tensor(v.boxes()))).double().numpy()
    assert ((pred - target) ** 2).sum(1).mean() < 0.5 * (target ** 2).sum(1).mean()
    assert m.predicts_head_pose and len(m.landmarks3d["names"]) >= 60
    video = load_video(use)
    # the usage pose fitted to the landmarks below the headset is close to the truth
    (R, t, p), src = usage_poses(m, video, "landmarks")
    Rt, tt, pt = video.poses
    assert src == "landmarks"
    for f in range(len(video)):
        assert _angle_deg(Rt[f], R[f]) < 1.5
        assert np.linalg.norm((p - R[f] @ p + t[f]) - (pt - Rt[f] @ pt + tt[f])) < 1e-2  # same motion of the origin
    assert usage_poses(m, video, "auto")[1] == "file" and usage_poses(m, video, "image") == (None, "image")
    # the calibration learned in registration is saved, loaded and moves the lower-landmark poses
    cal = m.pose_calibration
    assert cal is not None and len(cal["fit_names"]) == 12 and len(cal["names"]) == 43 and len(cal["basis"]) == 8
    m.pose_calibration = None
    (R0, t0, _), _ = usage_poses(m, video, "landmarks")
    m.pose_calibration = cal
    moved = [_angle_deg(a, b) for a, b in zip(R, R0)]
    assert 1e-4 < max(moved) < 1.0
    conf = json.loads((tmp_path / "m" / "config.json").read_text())
    conf["pose_calibration"]["weights"] = conf["pose_calibration"]["weights"][:-1]
    (tmp_path / "m" / "config.json").write_text(json.dumps(conf))
    with pytest.raises(AvatarError, match="pose_calibration is malformed"):
        load_hfm(tmp_path / "m")
    # the default calibration weighs the landmarks (saved and loaded with it); the usage fit uses
    # the weights, and equal weights give other poses
    from dataclasses import replace

    from geoface.hfm.train import calibrate_usage_poses, save_hfm

    assert m.cfg.pose_calibration_weighted
    assert len(cal["fit_weights"]) == 12 and abs(np.mean(cal["fit_weights"]) - 1) < 1e-9
    v.poses = (fit["R"], fit["t"], fit["pivot"])
    m.cfg = replace(m.cfg, pose_calibration_weighted=False)
    assert "fit_weights" not in calibrate_usage_poses(m, v)
    (Rp, _, _), _ = usage_poses(m, video, "landmarks")
    assert 1e-4 < max(_angle_deg(a, b) for a, b in zip(R, Rp)) < 1.0
    m.cfg, m.pose_calibration = replace(m.cfg, pose_calibration_weighted=True), cal
    save_hfm(m, tmp_path / "mw")
    assert np.allclose(load_hfm(tmp_path / "mw").pose_calibration["fit_weights"], cal["fit_weights"])
    conf = json.loads((tmp_path / "mw" / "config.json").read_text())
    conf["pose_calibration"]["fit_weights"][0] = -1.0
    (tmp_path / "mw" / "config.json").write_text(json.dumps(conf))
    with pytest.raises(AvatarError, match="fit_weights"):
        load_hfm(tmp_path / "mw")
    ev = evaluate_hmd(m, video, poses="landmarks")
    assert 5 < ev["psnr_face"] < 60 and ev["poses"] == "landmarks"
    # the calibration keeps how far the registration's expressions spread; a usage video whose mouth
    # is stretched beyond them lies beyond on every frame, and its usage poses come with a warning
    import warnings

    from geoface.errors import GeofaceWarning
    from geoface.avatar.capture import IBUG68_NAMES
    from geoface.hfm.usage import expression_coverage

    assert "score_sd" not in cal and expression_coverage(m, video) is None  # 12 frames: too few for 8 components
    assert "expression_beyond" not in ev
    m.cfg = replace(m.cfg, pose_calibration=2)
    cal2 = calibrate_usage_poses(m, v)
    assert len(cal2["score_sd"]) == 2 and cal2["score_reach"] > 1
    save_hfm(m, tmp_path / "m2c")
    m.cfg, m.pose_calibration = replace(m.cfg, pose_calibration=8), cal
    m2 = load_hfm(tmp_path / "m2c")
    assert np.allclose(m2.pose_calibration["score_sd"], cal2["score_sd"])
    cov = expression_coverage(m2, video)
    assert 0 <= cov["expression_beyond"] <= 1 and cov["expression_reach_median"] < 3
    assert evaluate_hmd(m2, video, poses="landmarks")["expression_beyond"] == cov["expression_beyond"]
    wide = video.landmarks.copy()
    mouth = [video.names.index(n) for n in IBUG68_NAMES[48:]]
    mid = wide[:, mouth].mean(1, keepdims=True)
    wide[:, mouth] = mid + 2.0 * (wide[:, mouth] - mid)
    stretched = replace(video, landmarks=wide)
    got = expression_coverage(m2, stretched)
    assert got["expression_beyond"] == 1.0 and got["expression_reach_median"] > 1
    with pytest.warns(GeofaceWarning, match="beyond any the registration video showed"):
        usage_poses(m2, stretched, "landmarks")
    with warnings.catch_warnings():
        warnings.simplefilter("error", GeofaceWarning)
        usage_poses(m2, stretched, "image")  # no landmark poses, nothing to say
        m2.pose_calibration = {k: v for k, v in cal2.items() if not k.startswith("score_")}  # saved before the spreads
        assert expression_coverage(m2, stretched) is None
        usage_poses(m2, stretched, "landmarks")
    conf = json.loads((tmp_path / "m2c" / "config.json").read_text())
    conf["pose_calibration"]["score_sd"] = [1.0] * 3
    (tmp_path / "m2c" / "config.json").write_text(json.dumps(conf))
    with pytest.raises(AvatarError, match="score_sd"):
        load_hfm(tmp_path / "m2c")
    # usage_landmarks "stable": the calibration and the usage poses use the 8 stable lower landmarks;
    # a calibration learned on the other set is not applied to them (the uncalibrated fit instead)
    from geoface.avatar.head_pose import LOWER_STABLE_NAMES, solve_poses as solve

    m.cfg = replace(m.cfg, usage_landmarks="stable")
    known = dict(zip(m.landmarks3d["names"], np.asarray(m.landmarks3d["points"])))
    use8 = [n for n in video.names if n in LOWER_STABLE_NAMES and n in known]
    P8 = np.array([known[n] for n in use8])
    plain = solve(video.camera, P8, video.landmarks[:, [video.names.index(n) for n in use8]], P8.mean(0))
    (Rs, _, _), _ = usage_poses(m, video, "landmarks")  # the 12-point calibration does not fit: left out
    assert max(_angle_deg(a, b) for a, b in zip(Rs, plain["R"])) < 0.05
    cal8 = calibrate_usage_poses(m, v)
    assert sorted(cal8["fit_names"]) == sorted(use8) and len(use8) == 8 and len(cal8["fit_weights"]) == 8
    (R8, _, _), src = usage_poses(m, video, "landmarks")
    assert src == "landmarks" and 1e-4 < max(_angle_deg(a, b) for a, b in zip(R8, plain["R"])) < 1.0
    for f in range(len(video)):
        assert _angle_deg(Rt[f], R8[f]) < 1.5
    m.cfg, m.pose_calibration = replace(m.cfg, usage_landmarks="lower"), cal
    with pytest.raises(AvatarError, match="usage_landmarks"):
        HFMConfig(usage_landmarks="upper")
    # headset_pose: with 18 whole headset masks (the three frames six times) the calibrated poses
    # are also moved by the headset's silhouette, within what the landmarks allow; with three the
    # masks are too few for its model and the calibrated poses stay
    tile = lambda a: np.concatenate([a] * 6)  # noqa: E731
    v18 = replace(video, frames=tile(video.frames), masks=tile(video.masks), landmarks=tile(video.landmarks),
                  hmd_masks=tile(video.hmd_masks), gt=None, gt_static_upper=None, poses=None)
    m.cfg = replace(m.cfg, headset_pose=True)
    (Rh, th, ph), src = usage_poses(m, v18, "landmarks")
    assert src == "landmarks+headset"
    assert 1e-6 < max(_angle_deg(a, b) for a, b in zip(tile(R), Rh))
    for f in range(18):
        assert _angle_deg(Rt[f % 3], Rh[f]) < 1.5
    assert usage_poses(m, video, "landmarks")[1] == "landmarks"
    m.cfg = replace(m.cfg, headset_pose=False)
    m.landmarks3d = None
    with pytest.raises(AvatarError, match="need 4"):
        usage_poses(m, video, "landmarks")
    with pytest.raises(AvatarError, match="no head_poses.npz"):
        (reg / "head_poses.npz").rename(tmp_path / "hp.npz")
        try:
            train_hfm(reg, tmp_path / "m2", cfg, progress=False, log=None, poses="file")
        finally:
            (tmp_path / "hp.npz").rename(reg / "head_poses.npz")


def test_pose_params_round_trip():
    from geoface.hfm.model import HFMConfig, HFMModel
    from geoface.splat.gaussians import Gaussians

    n = 500
    X = torch.randn(n, 3) * 0.1
    g = Gaussians(X, torch.full((n, 3), math.log(0.005)), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                  torch.zeros(n), torch.rand(n, 3))
    m = HFMModel(g, HFMConfig(), 0.0)
    R, t, piv = rodrigues([0.1, -0.2, 0.05]), np.array([0.004, -0.002, 0.01]), np.array([0.0, -0.1, 0.02])
    q = torch.tensor(m.pose_params_of(R, t, piv), dtype=torch.float32)
    R2, t2, c = (a.double().numpy() for a in m.head_pose_from_params(q))
    P = X.double().numpy()
    assert np.allclose((P - c) @ R2.T + c + t2, (P - piv) @ R.T + piv + t, atol=1e-6)


def test_landmarks_without_names_are_the_ibug_68(ict_capture, tmp_path):
    import shutil

    reg, _ = ict_capture
    d = tmp_path / "v"
    shutil.copytree(reg, d)
    lm = json.loads((d / "landmarks.json").read_text())
    (d / "landmarks.json").write_text(json.dumps({"points": lm["points"]}))
    assert load_video(d).names == list(IBUG68_NAMES)
    (d / "landmarks.json").write_text(json.dumps({"names": lm["names"][:10], "points": lm["points"]}))
    with pytest.raises(CaptureError, match="10 names but 68 points"):
        load_video(d)


def test_cli_ict_capture_and_pose_sources(ict_capture, tmp_path, capsys):
    """``hmd train --poses`` / ``hmd eval --poses`` take their sources, and a missing pose file is
    a one-line error (``hmd synth --head ict`` is make_ict_hmd, tested above)."""
    from geoface.cli import main

    reg, use = ict_capture
    assert main(["hmd", "synth", "-o", str(reg.parent), "--head", "ict", "-q"]) == 2  # never into a non-empty folder
    capsys.readouterr()
    assert main(["hmd", "synth", "-o", str(tmp_path / "r"), "--head", "ict", "--frames", "20", "--rom", "1", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "range of motion" in err[0] and not (tmp_path / "r").exists()
    md = tmp_path / "m"
    assert main(["hmd", "train", str(reg), "-o", str(md), "--iters", "3", "--no-densify", "--poses", "landmarks",
                 "--device", "cpu", "-q"]) == 0
    assert "fitted to" in capsys.readouterr().out
    assert main(["hmd", "eval", str(md), str(use), "--poses", "landmarks"]) == 0
    assert "head poses: landmarks" in capsys.readouterr().out
    # three usage masks are too few for the headset's model: the option runs and says the source
    assert main(["hmd", "eval", str(md), str(use), "--poses", "landmarks", "--headset-pose"]) == 0
    assert "head poses: landmarks)" in capsys.readouterr().out
    (use / "head_poses.npz").rename(tmp_path / "hp.npz")
    try:
        assert main(["hmd", "eval", str(md), str(use), "--poses", "file"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no head_poses.npz" in err[0]
    finally:
        (tmp_path / "hp.npz").rename(use / "head_poses.npz")
    assert main(["hmd", "train", str(reg), "-o", str(tmp_path / "m2"), "--iters", "3", "--device", "cuda:99", "-q"]) == 2


def test_corrected_pose_turns_the_head_about_its_centre_before_the_tracked_pose():
    from geoface.avatar.corrections import corrected_pose

    rng = np.random.default_rng(3)
    R, t, p, c = rodrigues(rng.normal(size=3) * 0.3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    w, d = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.01
    X = rng.normal(size=(5, 3))
    want = ((X - c) @ rodrigues(w).T + c + d - p) @ R.T + p + t
    Rn, tn, pn = (a.numpy() for a in corrected_pose(*(torch.tensor(a) for a in (R, t, p, w, d, c))))
    assert np.allclose((X - pn) @ Rn.T + pn + tn, want, atol=1e-12)
    Rz, tz, _ = corrected_pose(*(torch.tensor(a) for a in (R, t, p, 0 * w, 0 * d, c)))
    assert np.allclose(Rz.numpy(), R) and np.allclose(tz.numpy(), t)


def test_pose_corrections_learned_with_the_image_undo_tracking_errors(ict_capture):
    """Frames rendered by a fixed avatar at the true poses, the poses then turned 2° and moved
    3 mm: the per-frame corrections that training learns with the image loss bring them back."""
    from geoface.mesh.io import load_mesh
    from geoface.hfm import HFMConfig
    from geoface.hfm.train import _PoseRefinement, build_model
    from geoface.splat.rasterizer import rasterize

    reg, _ = ict_capture
    v = load_video(reg, need_mesh=True, frames=slice(1, 3))
    cfg = HFMConfig(n_keys=64, crop=64, lr_pose=4e-3)
    model = build_model(v, cfg, load_mesh(v.mesh_path))
    theta = torch.zeros(1, cfg.latent_dim)
    R, t, p = v.poses
    with torch.no_grad():
        frames = [rasterize(model.deform(theta, (R[f], t[f], p)), v.camera)[0] for f in range(len(v))]
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(len(v), 3))
    Rp = np.stack([rodrigues(np.radians(2.0) * a / np.linalg.norm(a)) @ R[f] for f, a in enumerate(axes)])
    tp = t + 0.003 * rng.normal(size=t.shape) / np.sqrt(3)
    v.poses = (Rp, tp, p)
    refine = _PoseRefinement(v, model, cfg, "cpu")
    # the corrected pose is the tracked pose's motion after the correction's; only the upper face
    # (above y_t) passes gradient to the correction
    with torch.no_grad():
        refine.d_rot[0] = torch.tensor([0.01, -0.02, 0.005])
    g0, g1 = refine.posed(theta, 0), model.deform(theta, refine.pose(0))
    torch.testing.assert_close(g0.means, g1.means)
    torch.testing.assert_close(g0.quats, g1.quats, atol=1e-2, rtol=0)  # orientations: the tracked pose's
    up = model.upper_mask()
    assert 0 < int(up.sum()) < len(up)
    g0.means[~up].sum().backward()
    assert refine.d_rot.grad is None or not refine.d_rot.grad.any()
    refine.posed(theta, 0).means[up].sum().backward()
    assert refine.d_rot.grad[0].abs().sum() > 0
    refine.opt.zero_grad()
    with torch.no_grad():
        refine.d_rot.zero_()

    def errors():
        Rc, tc, pc = v.poses
        return (max(_angle_deg(R[f], Rc[f]) for f in range(len(v))),
                max(np.linalg.norm(t[f] - tc[f]) for f in range(len(v))))  # the pivot's motion

    before = errors()
    sweeps = 80
    for k in range(sweeps):
        for f in range(len(v)):
            rgb = rasterize(refine.posed(theta, f), v.camera)[0]
            (rgb - frames[f]).abs().mean().backward()
            model.zero_grad(set_to_none=True)
            refine.step(f, k / (sweeps - 1))
    info = refine.finish()
    after = errors()
    assert before[0] > 1.9 and after[0] < 0.2, (before, after)
    assert after[1] < 0.3 * before[1], (before, after)
    assert info["pose_refined"] and 1.0 < info["pose_correction_deg"][0] < 3.0


def test_training_corrects_the_landmark_poses_saves_them_and_calibrates_to_them(ict_capture, tmp_path):
    from geoface.mesh.io import load_mesh
    from geoface.hfm import HFMConfig, load_hfm, train_hfm
    from geoface.hfm.io import load_registration_poses

    reg, _ = ict_capture
    cfg = HFMConfig(iters=40, warmup=0.2, densify=False, seed=0, n_keys=64, crop=64, pose_refine=True, lr_pose=4e-3)
    info = train_hfm(reg, tmp_path / "m", cfg, progress=False, log=None, poses="landmarks")
    assert info["pose_refined"] and 0 < info["pose_correction_deg"][0] <= info["pose_correction_deg"][1] < 2.0
    v = load_video(reg, need_mesh=True)
    mesh = load_mesh(v.mesh_path)
    fit = poses_from_landmarks(v, mesh.V, mesh.F)
    R, t, p = load_registration_poses(tmp_path / "m", len(v))
    moved = [_angle_deg(fit["R"][f], R[f]) for f in range(len(v))]
    assert np.allclose(p, fit["pivot"]) and 1e-3 < max(moved) < 2.0
    m = load_hfm(tmp_path / "m")
    assert m.cfg.pose_refine and m.pose_calibration is not None  # learned from the corrected poses
    with pytest.raises(AvatarError, match="registration poses of this model"):
        load_registration_poses(tmp_path / "m", len(v) + 1)
    np.savez(tmp_path / "m" / "registration_poses.npz", R=R[:, :2], t=t, pivot=p)
    with pytest.raises(AvatarError, match="registration poses of this model"):
        load_registration_poses(tmp_path / "m")
    # trained again into the folder without corrections: the stale file goes
    train_hfm(reg, tmp_path / "m", HFMConfig(iters=2, densify=False, n_keys=64, crop=64), progress=False, log=None,
              poses="landmarks")
    assert load_registration_poses(tmp_path / "m") is None


def _smile_rig(rng):
    """:func:`_lower_rig` with three expressions of its points (a faint sneer, a smile that lifts the
    nose points and widens the mouth, the jaw) and ``frames(T, lo, hi)``: T frames of random poses
    with expression weights uniform in [lo, hi] → (R, t, landmarks)."""
    cam, fit_names, names, P, piv = _lower_rig(rng)
    modes = np.zeros((3, 28, 3))
    modes[0, :4] = [0, 0.004, 0.002]  # sneer
    modes[0, 12:20] = [0, 0.003, 0]
    modes[1, :4] = [0.0, 0.003, -0.003]  # smile: the nose points lift and go back, the mouth widens
    modes[1, 12:28] = rng.normal(0, 0.004, (16, 3))
    modes[2, 20:28] = [0, -0.008, 0]  # jaw

    def frames(T, lo, hi):
        R = np.stack([rodrigues(rng.normal(0, 1, 3) * np.radians(4)) for _ in range(T)])
        t = rng.normal(0, 0.004, (T, 3))
        c = rng.uniform(lo, hi, (T, 3))
        obs = np.stack([cam.project((P + np.tensordot(c[f], modes, 1) - piv) @ R[f].T + piv + t[f])[0] for f in range(T)])
        return R, t, obs + rng.normal(0, 0.05, obs.shape)

    return cam, fit_names, names, P, piv, modes, frames


def test_expression_draws_teach_the_calibration_a_smile_registration_never_made():
    """Registration frames hold only the jaw and a faint sneer; the held-out frames a broad smile
    that lifts the 4 nose points and pulls the mouth. Calibrated on registration alone the smile's
    tilt stays (the regression never saw it); with each registration frame also seen twice with
    random expressions of a basis holding the smile (``expressions``, ``draws``), the tilt falls
    to under a third, while on frames like registration's the draws cost nothing."""
    from geoface.avatar.head_pose import apply_lower_calibration, calibrate_lower_poses

    rng = np.random.default_rng(8)
    cam, fit_names, names, P, piv, modes, frames = _smile_rig(rng)

    R, t, obs = frames(80, [0, 0, 0], [0.2, 0, 1])
    basis = {n: modes[:, k] for k, n in enumerate(names)}
    kw = dict(fit_names=fit_names, feature_names=names[12:], components=12, ridge=1e-4)
    plain = calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), **kw)
    drawn = calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), expressions=basis, draws=2, **kw)

    def tilt(cal, R2, obs2):
        low = solve_poses(cam, P[:12], obs2[:, :12], piv)
        Rc, _ = apply_lower_calibration(cal, cam, dict(zip(names, P)), obs2, names, low["R"], low["t"], piv)
        return np.mean([_angle_deg(R2[f], Rc[f]) for f in range(len(R2))])

    R2, _, obs2 = frames(20, [0, 0.8, 0], [0.2, 1.0, 1])  # a broad smile
    assert tilt(plain, R2, obs2) > 0.3 and tilt(drawn, R2, obs2) < tilt(plain, R2, obs2) / 3
    R3, _, obs3 = frames(20, [0, 0, 0], [0.2, 0, 1])  # as in registration
    assert tilt(drawn, R3, obs3) < tilt(plain, R3, obs3) + 0.05
    # the draws are seeded; a basis that lacks a name in use is not drawn from
    few = (R[:16], t[:16], piv)
    assert (calibrate_lower_poses(cam, names, P, obs[:16], names, few, expressions=basis, draws=1, **kw)
            == calibrate_lower_poses(cam, names, P, obs[:16], names, few, expressions=basis, draws=1, **kw))
    partial = {n: v for n, v in basis.items() if n != "m3"}
    assert (calibrate_lower_poses(cam, names, P, obs[:16], names, few, expressions=partial, draws=1, **kw)
            == calibrate_lower_poses(cam, names, P, obs[:16], names, few, **kw))


def test_expression_reach_tells_a_smile_registration_never_made():
    """Registration frames hold the jaw and a faint sneer; held-out frames like them stay within
    the calibration's reach (their distance from the mean face at most that of the farthest
    registration frame, which is exactly 1), while a broad smile lies beyond it on every frame."""
    from geoface.avatar.head_pose import calibrate_lower_poses, calibration_scores, expression_reach

    rng = np.random.default_rng(8)
    cam, fit_names, names, P, piv, modes, frames = _smile_rig(rng)

    R, t, obs = frames(80, [0, 0, 0], [0.2, 0, 1])
    cal = calibrate_lower_poses(cam, names, P, obs, names, (R, t, piv), fit_names=fit_names, feature_names=names[12:],
                                components=12, ridge=1e-4)
    assert len(cal["score_sd"]) == 12 and min(cal["score_sd"]) > 0 and cal["score_reach"] > 1

    def reach(obs2):
        low = solve_poses(cam, P[:12], obs2[:, :12], piv)
        return expression_reach(cal, calibration_scores(cal, cam, dict(zip(names, P)), obs2, names, low["R"], low["t"], piv))

    assert abs(reach(obs).max() - 1) < 1e-6  # the farthest registration frame
    alike = reach(frames(40, [0, 0, 0], [0.2, 0, 1])[2])
    smile = reach(frames(20, [0, 0.8, 0], [0.2, 1.0, 1])[2])
    assert (alike <= 1).mean() >= 0.9 and np.median(alike) < 0.8
    assert (smile > 1).all() and np.median(smile) > 2
    old = {k: v for k, v in cal.items() if k not in ("score_sd", "score_reach")}  # saved before the spreads were kept
    assert expression_reach(old, np.zeros((3, 12))) is None and expression_reach(cal, None) is None


def test_landmark_expressions_are_the_ict_blendshapes_in_the_heads_frame():
    """On the ICT-FaceKit mean head turned by 20°, scaled to metres and moved, the displacements of
    each landmark are the model's own, turned and scaled alike; brows and lids are left out;
    landmarks of other names are skipped, and too few iBUG names give None."""
    from geoface.avatar.head_pose import landmark_expressions
    from geoface.synth.ict import load_ict_model

    model = load_ict_model()
    base = model.shape(None)
    L = model.landmarks
    Q = rodrigues(np.radians([5.0, 20.0, -3.0]))
    pts = 0.01 * base[L] @ Q.T + [0.01, -0.02, 0.3]
    names = list(IBUG68_NAMES)
    got = landmark_expressions(names + ["ear"], np.r_[pts, [[0, 0, 0]]], model=model)
    keep = [n for n in model.expression_names if not n.startswith(("eye", "brow"))]
    assert set(got) == set(names) and len(keep) < len(model.expression_names)
    k = names.index("mouth_left")
    j = keep.index("mouthSmile_L")
    want = 0.01 * (model.shape(None, {"mouthSmile_L": 1.0}) - base)[L[k]] @ Q.T
    assert got["mouth_left"].shape == (len(keep), 3) and np.linalg.norm(want) > 1e-3
    assert np.allclose(got["mouth_left"][j], want, atol=1e-9)
    assert np.abs(got["eye_left_0"]).max() < 1e-3  # a smile barely moves the eye corners; no lid shapes kept
    assert landmark_expressions(names[:5], pts[:5], model=model) is None
