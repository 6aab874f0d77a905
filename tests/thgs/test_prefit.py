"""THGS's audio articulation fitted to the mouth landmarks before training (geoface.thgs.prefit),
batched kinematics, and the lip gap as the camera sees it."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface.avatar.kinematics import joint_transforms  # noqa: E402
from geoface.thgs.model import AudioArticulation, THGSConfig, THGSModel  # noqa: E402
from geoface.thgs.train import train_heldout_split  # noqa: E402
from geoface.thgs.data import load_talking, mouth_landmark_targets  # noqa: E402
from geoface.thgs.ict import make_ict_talking  # noqa: E402
from geoface.thgs.prefit import posed_points, prefit_articulation, prefit_training  # noqa: E402


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    d = make_ict_talking(tmp_path_factory.mktemp("talk") / "d", seconds=3.0, res=48, n_vertices=1500, map_res=128,
                         supersample=1, seed=4, quiet=True)
    return d, load_talking(d)


def _model(data, seed=0):
    torch.manual_seed(seed)
    m = THGSModel(data.template, THGSConfig(use_saam=False, seed=seed), data.audio.shape[1], len(data))
    A = m.audio_input(data.audio)
    m.audio_ref.copy_(torch.quantile(A, 0.02, dim=0))
    m.audio_scale.copy_(A.std(0).clamp_min(1e-3))
    m.tracked_joints.copy_(torch.as_tensor(data.tracked_joints))
    m.tracked_expr.copy_(torch.as_tensor(data.tracked_expr))
    return m, A


def _tracking(data):
    return [torch.as_tensor(a, dtype=torch.float32) for a in (data.rot, data.transl, data.expr)]


def test_batched_kinematics_and_articulation_match_frame_by_frame():
    g = torch.Generator().manual_seed(0)
    joints = torch.randn(4, 3, generator=g)
    parents = (-1, 0, 1, 1)
    rot, transl = torch.randn(5, 4, 3, generator=g) * 0.4, torch.randn(5, 3, generator=g)
    A = joint_transforms(joints, parents, rot, transl)
    assert A.shape == (5, 4, 4, 4)
    for t in range(5):
        torch.testing.assert_close(A[t], joint_transforms(joints, parents, rot[t], transl[t]), rtol=0, atol=1e-5)
    art = AudioArticulation(6, 4, 3)
    with torch.no_grad():
        for p in art.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 0.3)
    a = torch.randn(5, 6, generator=g)
    dr, de = art(a)
    assert dr.shape == (5, 4, 3) and de.shape == (5, 3)
    for t in range(5):
        torch.testing.assert_close(dr[t], art(a[t])[0], rtol=0, atol=1e-5)
        torch.testing.assert_close(de[t], art(a[t])[1], rtol=0, atol=1e-5)


def test_posed_points_are_the_model_s_own_gaussians(capture):
    """Batched over frames, the posed landmark Gaussians equal the avatar's forward pass (no SAAM)."""
    _, data = capture
    m, A = _model(data)
    with torch.no_grad():
        for p in m.artic.parameters():
            p.add_(torch.randn_like(p) * 0.2)
        m.leb.delta.add_(torch.randn_like(m.leb.delta) * 1e-3)
    idx = torch.tensor([int(i[0]) for i in m.gaussians_of(mouth_landmark_targets(data)[0])])
    frames = [0, 7, 30, 51]
    rot, transl, expr = (a[frames] for a in _tracking(data))
    with torch.no_grad():
        dr, de = m.artic(m.normalize_audio(A[frames]))
        P = posed_points(m, idx, rot + dr * (~m.tracked_joints)[:, None], transl, expr + de * ~m.tracked_expr)
        for k, t in enumerate(frames):
            X = m(data.rot[t], data.transl[t], data.expr[t], A[t]).means[idx]
            torch.testing.assert_close(P[k], X, rtol=0, atol=2e-6)


def test_prefit_recovers_an_articulation_that_made_the_landmarks(capture):
    """Landmarks made by a known audio → jaw and lips map (a randomly weighted network) are
    fitted to a hundredth of the error of the network left at rest, on frames it did not see too."""
    _, data = capture
    teacher, A = _model(data, seed=1)
    with torch.no_grad():
        for p in teacher.artic.parameters():
            p.add_(torch.randn_like(p) * 0.05)
    idx = [int(i[0]) for i in teacher.gaussians_of(mouth_landmark_targets(data)[0])]
    rot, transl, expr = _tracking(data)
    a = teacher.normalize_audio(A)
    with torch.no_grad():
        dr, de = teacher.artic(a)
        X = posed_points(teacher, idx, rot + dr * (~teacher.tracked_joints)[:, None], transl, expr + de * ~teacher.tracked_expr)
        pts = data.camera.project(X.reshape(-1, 3))[0].reshape(len(data), -1, 2)
    student, _ = _model(data, seed=2)
    tr, te = train_heldout_split(len(data), 0.2)
    info = prefit_articulation(student, a[tr], rot[tr], transl[tr], expr[tr], idx, pts[tr], data.camera, max_steps=300,
                               lr=1e-2)
    assert info["px_before"] > 1.0 and info["px_after"] < 0.05 * info["px_before"]
    assert 1 <= info["steps"] <= 300 and info["val_px"] < 0.1 * info["px_before"]
    with torch.no_grad():
        dr, de = student.artic(a[te])
        Xs = posed_points(student, idx, rot[te] + dr * (~student.tracked_joints)[:, None], transl[te],
                          expr[te] + de * ~student.tracked_expr)
        err = (data.camera.project(Xs.reshape(-1, 3))[0].reshape(len(te), -1, 2) - pts[te]).norm(dim=-1).mean()
    rest = (data.camera.project(posed_points(student, idx, rot[te], transl[te], expr[te]).reshape(-1, 3))[0]
            .reshape(len(te), -1, 2) - pts[te]).norm(dim=-1).mean()
    assert float(err) < 0.2 * float(rest)


def test_prefit_on_the_capture_opens_the_lips_with_the_person(capture):
    """On the capture's own (noisy) landmarks, the fitted articulation brings the landmark error
    to within 20% of the landmarks' noise and opens the lips in the image with the person's lips
    (r > 0.8 over the training frames)."""
    d, data = capture
    m, A = _model(data)
    tr, _ = train_heldout_split(len(data), 0.2)
    lv, px = mouth_landmark_targets(data)
    lmk = ([int(i[0]) for i in m.gaussians_of(lv)], px)
    info = prefit_training(m, data, tr, A, lmk)
    floor = 0.5 * np.sqrt(np.pi / 2)  # the mean distance of 2D noise of 0.5 px per axis
    assert info["px_after"] < info["px_before"] - 0.1 and info["px_after"] < 1.2 * floor
    meta = json.loads((d / "meta.json").read_text())
    lip = [int(i[0]) for i in m.gaussians_of(meta["lip_vertices"])]
    rot, transl, expr = (a[tr] for a in _tracking(data))
    with torch.no_grad():
        dr, de = m.artic(m.normalize_audio(A[tr]))
        X = posed_points(m, lip, rot + dr * (~m.tracked_joints)[:, None], transl, expr + de * ~m.tracked_expr)
        uv = data.camera.project(X.reshape(-1, 3))[0].reshape(-1, 2, 2)
    gap = (uv[:, 0] - uv[:, 1]).norm(dim=-1).numpy()
    true = np.asarray(meta["lip_gap_px"])[tr]
    # (60 frames of 200 audio features: the held-back block stops the fit early, short of the full spread)
    assert np.corrcoef(gap, true)[0, 1] > 0.8 and gap.std() > 0.25 * true.std()
    assert prefit_training(m, data, tr, A, None) == {}


def test_training_runs_the_prefit_once_and_the_evaluation_reports_the_image_gap(capture, tmp_path):
    from geoface.thgs.inference import load_thgs
    from geoface.thgs.train import train_thgs
    from geoface.thgs.eval import evaluate_thgs, true_lip_gaps_px

    d, data = capture
    info = train_thgs(d, tmp_path / "m", THGSConfig(iters=3, stage_scale=0.0, use_saam=False, seed=0,
                                                    artic_prefit=True), progress=False)
    assert info["artic_prefit"]["px_after"] < info["artic_prefit"]["px_before"]
    off = train_thgs(d, tmp_path / "off", THGSConfig(iters=3, stage_scale=0.0, use_saam=False, seed=0), progress=False)
    assert off["artic_prefit"] == {} and THGSConfig().artic_prefit is False  # off by default
    assert THGSConfig.from_dict({"iters": 10}).artic_prefit is False  # saved before the option: none
    ev = evaluate_thgs(load_thgs(tmp_path / "m"), data)
    assert ev["lip_gap_px_std_real"] > 0.5 and -1 <= ev["lip_gap_px_corr_real"] <= 1 and ev["lip_gap_px_std"] >= 0
    # without the stored image gap, the inner-lip landmarks stand in (their noise is 0.5 px)
    exact = true_lip_gaps_px(data)
    data.meta.pop("lip_gap_px")
    from_landmarks = true_lip_gaps_px(data)
    assert np.abs(from_landmarks - exact).mean() < 1.0 and np.corrcoef(from_landmarks, exact)[0, 1] > 0.8
