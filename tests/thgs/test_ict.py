"""THGS on ICT-FaceKit heads: the template's jaw and eyes, the talking captures, perturbed tracking."""
import json

import numpy as np
import pytest

from geoface.errors import CaptureError

torch = pytest.importorskip("torch")

from geoface.avatar.ict import ICTPerson  # noqa: E402
from geoface.avatar.kinematics import joint_transforms  # noqa: E402
from geoface.thgs.eval import head_pose_errors  # noqa: E402
from geoface.thgs.ict import (JOINT_NAMES, ict_template, is_mouth_blendshape, make_ict_talking,  # noqa: E402
                                    perturb_capture)
from geoface.errors import AvatarError  # noqa: E402


@pytest.fixture(scope="module")
def person_tpl():
    person = ICTPerson(np.random.default_rng(3), res=32, map_res=128, supersample=1)
    tpl, info = ict_template(person, 1500)
    return person, tpl, info


def _pose(tpl, rot, transl=None):
    A = joint_transforms(torch.tensor(tpl.joints), tpl.parents, torch.tensor(rot),
                         None if transl is None else torch.tensor(transl))
    M = torch.einsum("nj,jab->nab", torch.tensor(tpl.weights), A).numpy()
    return (M[:, :3, :3] @ tpl.V[..., None])[..., 0] + M[:, :3, 3]


def test_jaw_hinge_and_weights_reproduce_the_model_s_jaw_opening(person_tpl):
    """Rotating the fitted jaw joint by the fitted angle moves the template's vertices as the
    model's own jawOpen blendshape does (to a tenth of its motion on the parts that move), and
    the hinge sits where a jaw's does: behind the mouth, between the chin and the eyes."""
    person, tpl, info = person_tpl
    from scipy.spatial import cKDTree

    rv = np.asarray(info["jaw_rotvec"])
    assert 8 < np.degrees(np.linalg.norm(rv)) < 30  # a full opening turns the jaw 8–30°
    assert abs(rv[0]) > 0.9 * np.linalg.norm(rv)  # about the left-right axis
    rot = np.zeros((len(JOINT_NAMES), 3))
    rot[tpl.jaw] = rv
    moved = _pose(tpl, rot) - tpl.V
    _, near = cKDTree(person.V0).query(tpl.V)
    want = (person.shape({"jawOpen": 1.0}) - person.V0)[near]
    big = np.linalg.norm(want, axis=1) > 0.3 * np.linalg.norm(want, axis=1).max()
    err = np.linalg.norm(moved - want, axis=1)[big].mean() / np.linalg.norm(want, axis=1)[big].mean()
    assert err < 0.2, err
    lm = person.V0[person.rest.landmarks]
    hinge = tpl.joints[tpl.jaw]
    assert lm[8, 1] < hinge[1] < lm[36:48, 1].mean() + 0.01  # between chin and eyes
    assert hinge[2] < lm[48:68, 2].min() - 0.03  # well behind the lips
    # above the eyes the head barely moves with the jaw (as in the blendshape: skin stretch only)
    top = tpl.V[:, 1] > lm[36:48, 1].mean()
    assert np.linalg.norm(moved[top], axis=1).max() < 0.02 * np.linalg.norm(moved, axis=1).max()


def test_eyes_turn_about_their_centres_and_the_root_is_the_capture_s_pivot(person_tpl):
    person, tpl, _ = person_tpl
    for j in (4, 5):
        ball = tpl.weights[:, j] > 0.999
        assert ball.sum() > 20
        r = np.linalg.norm(tpl.V[ball] - tpl.joints[j], axis=1)
        assert r.std() < 0.15 * r.mean() and 0.008 < r.mean() < 0.016  # a sphere of ~1.2 cm about the joint
    # the tracker's pose (a root rotation and a translation) is the capture's rigid motion about the neck
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [0.1, -0.2, 0.05]).as_matrix()
    t = np.array([0.004, -0.002, 0.003])
    rot = np.zeros((len(JOINT_NAMES), 3))
    rot[0] = Rotation.from_matrix(R).as_rotvec()
    np.testing.assert_allclose(_pose(tpl, rot, t), (tpl.V - person.pivot) @ R.T + person.pivot + t, atol=1e-9)
    # the basis: the model's other 52 blendshapes, in metres
    assert tpl.n_expr == 52 and 0.002 < np.abs(tpl.expr_basis).max() < 0.05


def test_head_pose_errors_measure_angle_and_displacement(person_tpl):
    _, tpl, _ = person_tpl
    from scipy.spatial.transform import Rotation

    T, J = 4, len(JOINT_NAMES)
    rot = np.zeros((T, J, 3))
    rot[:, 0] = Rotation.from_euler("y", [[0], [5], [10], [15]], degrees=True).as_rotvec()
    tr = np.zeros((T, 3))
    e = head_pose_errors(tpl, rot, tr, rot, tr)
    assert e["rot_deg_max"] < 1e-6 and e["mm_max"] < 1e-6
    e = head_pose_errors(tpl, rot, tr + [0.005, 0, 0], rot, tr)
    assert e["rot_deg_max"] < 1e-6 and abs(e["mm_mean"] - 5.0) < 1e-6
    still = np.zeros_like(rot)
    e = head_pose_errors(tpl, still, tr + [0.005, 0, 0], still, tr)
    assert e["mm_about_mean"] < 1e-6  # a constant shift is no error about the mean offset
    moved = tr + np.array([[0.005, 0, 0], [-0.005, 0, 0], [0.005, 0, 0], [-0.005, 0, 0]]) + [0, 0.003, 0]
    e = head_pose_errors(tpl, still, moved, still, tr)
    assert abs(e["mm_about_mean"] - 5.0) < 1e-6 and e["mm_mean"] > 5.5
    other = rot.copy()
    other[:, 2, 0] += np.radians(2.0)  # a nod on the head joint counts as much as one on the root
    e = head_pose_errors(tpl, other, tr, rot, tr)
    assert abs(e["rot_deg_mean"] - 2.0) < 1e-6 and e["rot_deg_about_mean"] < 1e-6
    other[::2, 2, 0] -= np.radians(4.0)  # ±2° about the same axis: 2° each about the mean offset
    e = head_pose_errors(tpl, other, tr, rot, tr)
    assert abs(e["rot_deg_about_mean"] - 2.0) < 1e-6 and abs(e["rot_deg_mean"] - 2.0) < 1e-6


def test_talking_capture_lets_the_audio_drive_the_mouth_and_perturbs_tracking(tmp_path):
    from geoface.thgs.data import load_talking

    d = make_ict_talking(tmp_path / "talk", seconds=2.0, res=32, n_vertices=1500, map_res=128, supersample=1,
                         seed=2, quiet=True)
    data = load_talking(d)
    meta = json.loads((d / "meta.json").read_text())
    assert len(data) == 50 and data.frames.shape[1:] == (32, 32, 3)
    names = meta["expression_names"]
    mouth = [i for i, n in enumerate(names) if is_mouth_blendshape(n)]
    assert len(mouth) > 10 and np.abs(data.expr[:, mouth]).max() == 0  # the tracker leaves the mouth out
    jaw, env = np.asarray(meta["jaw_open"]), np.asarray(meta["envelope"])
    assert jaw.max() > 0.2 and np.corrcoef(jaw, env)[0, 1] > 0.5  # the loudness opens the jaw
    gap = np.asarray(meta["lip_gap_m"])  # the true opening of the lips follows the loudness
    assert gap.max() > 0.01 and np.corrcoef(gap, env)[0, 1] > 0.5
    from geoface.thgs.model import THGSConfig, THGSModel
    from geoface.thgs.eval import lip_gaps

    model = THGSModel(data.template, THGSConfig(use_saam=False), data.audio.shape[1], 0)
    rest = np.linalg.norm(np.subtract(*data.template.V[meta["lip_vertices"]]))
    g = lip_gaps(model, data, range(len(data)), meta["lip_vertices"])  # no audio module: the lips stay as tracked
    assert np.abs(g - rest).max() < 1e-3 and 0 < rest < 0.006
    truth = np.load(d / "poses_true.npz")
    np.testing.assert_array_equal(truth["rot"], data.rot)  # no perturbation asked
    # the tracker measures the rigid head pose (the root) and the expressions outside the mouth
    assert data.tracked_joints.tolist() == [True] + [False] * 5
    np.testing.assert_array_equal(data.tracked_expr, [not is_mouth_blendshape(n) for n in names])
    # the tracker's 2D landmarks: the inner lips' landmarks open as the true lips do
    from geoface.avatar.capture import IBUG68_NAMES
    from geoface.thgs.data import mouth_landmark_targets

    assert data.landmarks.shape == (50, 68, 2) and data.landmark_names == list(IBUG68_NAMES)
    lm_gap = np.linalg.norm(data.landmarks[:, 62] - data.landmarks[:, 66], axis=1)
    assert np.corrcoef(lm_gap, gap)[0, 1] > 0.5  # 32 px wide: the gap is a few pixels, the noise 0.5
    verts, pts = mouth_landmark_targets(data)
    assert len(verts) == 20 and pts.shape == (50, 20, 2)
    np.testing.assert_array_equal(verts, data.template.landmark_vertices[48:68])
    p = perturb_capture(d, tmp_path / "pert", (3.0, 5.0), seed=1)
    pert = load_talking(p)
    np.testing.assert_array_equal(pert.tracked_expr, data.tracked_expr)
    np.testing.assert_array_equal(pert.tracked_joints, data.tracked_joints)
    np.testing.assert_array_equal(pert.frames, data.frames)
    e = head_pose_errors(data.template, pert.rot, pert.transl, truth["rot"], truth["transl"])
    assert abs(e["rot_deg_mean"] - 3.0) < 1e-6 and abs(e["rot_deg_max"] - 3.0) < 1e-6
    # 5 mm of translation and a 3° turn about the neck, ~10 cm below the head's centre
    assert 2.0 < e["mm_mean"] < 5.0 + 0.15 * 1000 * np.radians(3.0)
    with pytest.raises(AvatarError, match="poses_true"):
        perturb_capture(tmp_path / "pert_missing", tmp_path / "x", (1, 1))


def test_cli_talk_synth_ict_with_perturbed_tracking_trains_and_reports_pose_errors(tmp_path, capsys):
    from geoface.cli import main

    d = tmp_path / "t"
    assert main(["talk", "synth", "-o", str(d), "--head", "ict", "--seconds", "0.4", "--res", "32", "--vertices", "1000", "--landmarks", "oracle",
                 "--perturb", "3,5", "-q"]) == 0
    assert "off by 3° / 5 mm" in capsys.readouterr().out
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "m"), "--iters", "3", "--heldout", "0.2", "-q"]) == 0
    from geoface.thgs.model import THGSConfig
    from geoface.thgs.inference import load_thgs
    from geoface.cli.talk import THGS_AUDIO_WINDOW, THGS_LANDMARK_WEIGHT, THGS_LR_POSE, THGS_POSE_DECAY

    assert THGS_LANDMARK_WEIGHT == THGSConfig().lambda_landmarks == load_thgs(tmp_path / "m").cfg.lambda_landmarks
    assert THGS_AUDIO_WINDOW == THGSConfig().audio_window == load_thgs(tmp_path / "m").cfg.audio_window
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "mw"), "--iters", "2", "--audio-window", "3", "-q"]) == 0
    assert load_thgs(tmp_path / "mw").cfg.audio_window == 3
    c = load_thgs(tmp_path / "m").cfg
    assert (THGS_LR_POSE, THGS_POSE_DECAY) == (THGSConfig().lr_pose, THGSConfig().pose_decay) == (c.lr_pose, c.pose_decay)
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "mp"), "--iters", "2", "--lr-pose", "0.003",
                 "--pose-decay", "1", "-q"]) == 0
    assert (load_thgs(tmp_path / "mp").cfg.lr_pose, load_thgs(tmp_path / "mp").cfg.pose_decay) == (0.003, 1.0)
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "mp2"), "--pose-decay", "0.5", "-q"]) == 2
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "mw2"), "--audio-window", "-1", "-q"]) == 2
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "m0"), "--iters", "2", "--landmark-weight", "0", "-q"]) == 0
    assert load_thgs(tmp_path / "m0").cfg.lambda_landmarks == 0
    assert main(["talk", "train", str(d), "-o", str(tmp_path / "m1"), "--landmark-weight", "-1", "-q"]) == 2
    assert main(["talk", "eval", str(tmp_path / "m"), str(d), "--json", str(tmp_path / "e.json")]) == 0
    assert "corrected" in capsys.readouterr().out
    e = json.loads((tmp_path / "e.json").read_text())
    assert abs(e["pose_before"]["rot_deg_mean"] - 3.0) < 1e-6 and "mouth_open_std_real" in e
    for bad in (["--perturb", "3"], ["--perturb", "a,b"], ["--perturb", "-1,2"]):
        assert main(["talk", "synth", "-o", str(tmp_path / "x"), "--head", "ict", *bad]) == 2
    assert main(["talk", "synth", "-o", str(tmp_path / "x"), "--perturb", "3,5"]) == 2  # the procedural head has no truth file
    assert "needs --head ict" in capsys.readouterr().err


def test_template_vertices_sit_on_the_landmarks_and_project_onto_the_capture_s_points(person_tpl, tmp_path):
    """The ICT template carries a vertex exactly at each of the 68 landmarks (distinct vertices),
    saved and loaded with it; posed by the true poses of a capture, the mouth landmarks' vertices
    project onto the capture's landmarks.json within the detector noise plus what LBS misses."""
    from geoface.avatar.template import Template
    from geoface.thgs.data import landmark_loss, load_talking, mouth_landmark_targets

    person, tpl, _ = person_tpl
    np.testing.assert_allclose(tpl.V[tpl.landmark_vertices], person.V0[person.rest.landmarks], atol=1e-12)
    assert len(set(tpl.landmark_vertices.tolist())) == 68
    tpl.save(tmp_path / "t.npz")
    back = Template.load(tmp_path / "t.npz")
    assert back.landmark_names == tpl.landmark_names
    np.testing.assert_array_equal(back.landmark_vertices, tpl.landmark_vertices)
    with pytest.raises(AvatarError, match="landmark"):
        Template(tpl.V, tpl.F, tpl.joints, tpl.parents, tpl.weights, tpl.expr_basis, tpl.head_mask, tpl.mouth_box,
                 tpl.joint_names, tpl.jaw, ["a", "b"], [0, len(tpl.V)])
    # a capture: at rest-mouth frames the posed template lands on the tracker's points
    d = make_ict_talking(tmp_path / "talk", seconds=1.0, res=64, n_vertices=1500, map_res=128, supersample=1,
                         seed=4, quiet=True)
    data = load_talking(d)
    from geoface.thgs.model import THGSConfig, THGSModel

    model = THGSModel(data.template, THGSConfig(use_saam=False, use_audio_pose=False), data.audio.shape[1], 0)
    verts, pts = mouth_landmark_targets(data)
    truth = np.load(d / "poses_true.npz")
    meta = json.loads((d / "meta.json").read_text())
    quiet = int(np.argmin(meta["jaw_open"]))
    with torch.no_grad():
        gd = model(truth["rot"][quiet], truth["transl"][quiet], truth["expr"][quiet])
        uv = data.camera.project(gd.means[torch.as_tensor(verts)])[0].numpy()
        err = np.linalg.norm(uv - pts[quiet], axis=1)
        assert np.median(err) < 1.5, err  # 64 px wide: 1.5 px ≈ 2 mm
        loss0 = float(landmark_loss(gd.means[torch.as_tensor(verts)], data.camera, pts[quiet]))
        far = float(landmark_loss(gd.means[torch.as_tensor(verts)] + torch.tensor([0.01, 0, 0]), data.camera, pts[quiet]))
    assert 0 <= loss0 < far
    bad = tmp_path / "talk" / "landmarks.json"
    bad.write_text(json.dumps({"points": [[[0, 0]]]}))
    with pytest.raises(CaptureError, match="landmarks"):
        load_talking(d)


@pytest.mark.slow
def test_mouth_landmarks_teach_the_audio_to_open_the_jaw(tmp_path):
    """Trained with the capture's mouth landmarks, the audio articulation opens the jaw as the
    true jaw opens (r > 0.5 over the frames), by a tenth of the true range or more within 150
    steps (without them it stays within a hundredth of a degree on the 12 s capture of the docs)."""
    from geoface.thgs.model import THGSConfig
    from geoface.thgs.inference import load_thgs
    from geoface.thgs.train import train_thgs
    from geoface.thgs.data import load_talking

    d = make_ict_talking(tmp_path / "talk", seconds=2.5, res=40, n_vertices=1200, map_res=128, supersample=1,
                         seed=5, quiet=True)
    meta = json.loads((d / "meta.json").read_text())
    jaw_true = np.asarray(meta["jaw_open"])
    cfg = THGSConfig(iters=150, stage_scale=0.001, use_saam=False, use_leb=False, heldout=0.0, seed=0)
    train_thgs(d, tmp_path / "m", cfg, progress=False, log=None)
    m = load_thgs(tmp_path / "m")
    with torch.no_grad():
        jaw = np.array([float(m.artic(m.normalize_audio(a))[0][m.template.jaw].norm())
                        for a in m.audio_input(load_talking(d).audio)])
    full = np.linalg.norm(meta["jaw_rotvec"])
    assert np.corrcoef(jaw, jaw_true)[0, 1] > 0.5
    assert np.ptp(jaw) > 0.1 * full * np.ptp(jaw_true)


def test_landmark_term_can_leave_the_pose_corrections_alone(tmp_path):
    """By default (``landmarks_pose=False``) a training step moves the drawn frame's pose
    corrections exactly as it does without the landmark term, while the landmark term still
    reaches the networks; with ``landmarks_pose=True`` it moves the corrections too."""
    from geoface.thgs.model import THGSConfig
    from geoface.thgs.inference import load_thgs
    from geoface.thgs.train import train_thgs

    d = make_ict_talking(tmp_path / "talk", seconds=1.0, res=32, n_vertices=1200, map_res=128, supersample=1,
                         seed=3, quiet=True)
    p = perturb_capture(d, tmp_path / "pert", (2.0, 3.0), seed=0)  # corrections with something to correct
    models = {}
    for name, kw in {"off": {"lambda_landmarks": 0.0}, "nets": {"lambda_landmarks": 100.0},
                     "all": {"lambda_landmarks": 100.0, "landmarks_pose": True}}.items():
        cfg = THGSConfig(iters=1, stage_scale=0.0, heldout=0.0, seed=0, **kw)  # every stage on, one step
        train_thgs(p, tmp_path / name, cfg, progress=False, log=None)
        models[name] = load_thgs(tmp_path / name)
    off, nets, full = (models[k] for k in ("off", "nets", "all"))
    assert float(off.d_rot.detach().abs().max()) > 0 and float(off.d_transl.detach().abs().max()) > 0
    for k in ("d_rot", "d_transl", "d_expr"):
        assert torch.equal(getattr(off, k), getattr(nets, k)), k
    assert not torch.equal(off.d_rot, full.d_rot)
    changed = [not torch.equal(a, b) for a, b in zip(off.artic.parameters(), nets.artic.parameters())]
    assert any(changed)  # the landmark term trained the audio articulation
    # model folders saved before the option were trained with the landmarks moving the poses
    assert THGSConfig.from_dict({"iters": 5}).landmarks_pose is True and THGSConfig().landmarks_pose is False
