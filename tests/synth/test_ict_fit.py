"""Fitting the ICT model to 68 landmarks: pose and landmarks recovered on synthetic photos."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geoface import GeofaceError
from geoface.synth.ict import load_ict_model, random_expression
from geoface.synth.ict_fit import fit_landmarks, load_landmarks, project

W = H = 1024


@pytest.fixture(scope="module")
def model():
    return load_ict_model()


def _photo(model, seed):
    """A random person, expression and pose seen by a random pinhole camera: the true landmarks."""
    rng = np.random.default_rng(seed)
    V = model.shape(rng.standard_normal(model.n_identities),
                    random_expression(rng, model.expression_names, count=2, strength=0.7), "skin")
    ypr = rng.uniform([-30, -15, -10], [30, 15, 10])
    R = Rotation.from_euler("yxz", ypr, degrees=True).as_matrix() @ np.diag([1.0, -1.0, -1.0])  # facing the camera
    f = rng.uniform(1500, 3000)
    t = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), f / W * 35])  # the face ~430 px wide
    return project(V[model.view("skin").landmarks], R, t, f, (W / 2, H / 2)), R, f, rng


@pytest.mark.parametrize("seed", [1, 6, 8])
def test_pose_and_landmarks_are_recovered(model, seed):
    truth, R, f, rng = _photo(model, seed)
    noisy = truth + rng.normal(0, 0.5, truth.shape)  # a detector's 0.5 px
    fit = fit_landmarks(model, noisy, (W, H), focal=f)
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(fit.R @ R.T).as_rotvec()))
    head = fit.head(model)
    err = np.linalg.norm(project(head.V[head.landmarks], fit.R, fit.t, fit.focal, fit.centre) - truth, axis=1)
    assert angle < 2.0, angle
    assert err.mean() < 1.0 and np.quantile(err, 0.95) < 2.0, (err.mean(), err.max())
    assert fit.rms_px < 1.5


def test_unknown_focal_is_estimated(model):
    truth, R, f, rng = _photo(model, 5)
    fit = fit_landmarks(model, truth + rng.normal(0, 0.5, truth.shape), (W, H))
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(fit.R @ R.T).as_rotvec()))
    assert angle < 5.0 and fit.rms_px < 1.5 and 0.4 * f < fit.focal < 2.5 * f


def test_landmark_files(tmp_path):
    L = np.arange(136, dtype=float).reshape(68, 2)
    (tmp_path / "a.json").write_text(json.dumps({"image_size": [640, 480], "landmarks": L.tolist()}))
    (tmp_path / "b.txt").write_text("\n".join(f"{x} {y}" for x, y in L))
    (tmp_path / "c.pts").write_text("version: 1\nn_points: 68\n{\n" + "\n".join(f"{x} {y}" for x, y in L) + "\n}\n")
    np.save(tmp_path / "d.npy", L)
    for name in ("a.json", "b.txt", "c.pts", "d.npy"):
        got, size = load_landmarks(tmp_path / name)
        assert np.array_equal(got, L) and size == ((640, 480) if name == "a.json" else None)
    (tmp_path / "bad.json").write_text(json.dumps({"landmarks": L[:60].tolist()}))
    with pytest.raises(GeofaceError, match="68"):
        load_landmarks(tmp_path / "bad.json")
    with pytest.raises(GeofaceError, match="no such"):
        load_landmarks(tmp_path / "none.json")


def test_heldout_landmarks_are_predicted_by_the_rest(model):
    from geoface.synth.ict_fit import heldout_errors

    truth, R, f, rng = _photo(model, 3)
    noisy = truth + rng.normal(0, 0.5, truth.shape)
    held = heldout_errors(model, noisy, (W, H), focal=f)
    fit = fit_landmarks(model, noisy, (W, H), focal=f)
    # each landmark predicted from the others lands near it (the face's shape holds), but further
    # than when it is fitted itself
    assert held.shape == (68,) and held.mean() < 2.0 and np.quantile(held, 0.95) < 4.0, (held.mean(), held.max())
    assert held.mean() > fit.residual_px.mean()
    # a landmark moved 40 px off the face is not predicted: its held-out error shows it
    bad = noisy.copy()
    bad[30] += 40.0
    assert heldout_errors(model, bad, (W, H), focal=f, folds=2)[30] > 30.0
    with pytest.raises(GeofaceError, match="at least 12"):
        fit_landmarks(model, noisy, (W, H), holdout=np.arange(68) > 5)
