"""THGS: templates, voxel LBS, LEB, SAAM, audio features, training and the CLI."""
from __future__ import annotations

import importlib.util
import json
import math

import numpy as np
import pytest
import torch

from geoface.avatar.audio import audio_features, envelope, log_mel
from geoface.errors import AvatarError
from geoface.avatar.template import Template, load_smplx, procedural_template
from geoface.thgs.model import AudioArticulation, ExpressionBlendshapes, SpatialAudioAttention, THGSConfig, THGSModel, VoxelSkinning, axis_angle_to_matrix, joint_transforms, lbs
from geoface.thgs.inference import load_thgs
from geoface.thgs.train import train_thgs
from geoface.thgs.eval import evaluate_thgs, mouth_openness


@pytest.fixture(scope="module")
def tpl():
    return procedural_template(2000, seed=0)


def _two_cluster_template():
    """Joint 0 at the origin owns a blob near y = 0; joint 1 at (0, 1, 0) owns a blob near y = 2."""
    rng = np.random.default_rng(0)
    A = rng.normal(0, 0.1, (200, 3))
    B = rng.normal(0, 0.1, (200, 3)) + [0, 2, 0]
    V = np.concatenate([A, B])
    W = np.zeros((400, 2))
    W[:200, 0] = 1
    W[200:, 1] = 1
    return Template(V, np.zeros((0, 3), int), [[0, 0, 0], [0, 1, 0]], [-1, 0], W, np.zeros((1, 400, 3)),
                    np.ones(400, bool), [[-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]], ["root", "child"])


def test_rodrigues_matches_closed_form_and_is_smooth_at_zero():
    w = torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)
    R = axis_angle_to_matrix(w)
    assert torch.allclose(R, torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64), atol=1e-12)
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    axis_angle_to_matrix(z).sum().backward()
    assert torch.isfinite(z.grad).all()


def test_joint_quaternions_are_exact_and_have_gradients_at_the_rest_pose():
    """LBS blends the joints' quaternions: they must match the matrices for every rotation
    (including half turns) and carry a gradient at the rest pose, where training starts."""
    from geoface.splat.gaussians import quat_to_rotmat, rotmat_to_quat_torch

    g = torch.Generator().manual_seed(0)
    w = torch.randn(500, 3, generator=g, dtype=torch.float64) * 2
    w[0] = 0
    w[1] = torch.tensor([math.pi, 0, 0])
    w[2] = torch.tensor([0, 0, math.pi - 1e-9])
    R = axis_angle_to_matrix(w)
    assert torch.allclose(quat_to_rotmat(rotmat_to_quat_torch(R)), R, atol=1e-12)
    J = torch.autograd.functional.jacobian(lambda v: rotmat_to_quat_torch(axis_angle_to_matrix(v)),
                                           torch.zeros(1, 3, dtype=torch.float64))
    # q = (cos|w|/2, sin(|w|/2) w/|w|): dq/dw = [0; I/2] at zero
    assert torch.allclose(J.reshape(4, 3), torch.cat([torch.zeros(1, 3), torch.eye(3) / 2]).double(), atol=1e-9)


def test_identity_pose_returns_the_canonical_gaussians(tpl):
    m = THGSModel(tpl, THGSConfig(audio_window=0), audio_dim=8)  # forward takes one frame's 8 features
    J, K = len(tpl.joints), tpl.n_expr
    with torch.no_grad():
        g = m(np.zeros((J, 3)), np.zeros(3), np.zeros(K), torch.zeros(8))
    c = m.gaussians
    assert torch.allclose(g.means, c.means, atol=1e-6)
    assert torch.allclose(g.quats, c.quats / c.quats.norm(dim=-1, keepdim=True), atol=1e-6)
    assert torch.equal(g.log_scales, c.log_scales)
    # the mesh init puts each Gaussian's normal on its vertex normal; a tilt is penalised
    assert abs(float(m.normal_loss().detach())) < 1e-6
    with torch.no_grad():
        c.quats.copy_(torch.tensor([math.cos(0.5), math.sin(0.5), 0, 0]).expand_as(c.quats))
    assert float(m.normal_loss().detach()) > 0.05


def test_gaussians_of_finds_each_vertex_gaussians_and_refuses_an_unbound_vertex(tpl):
    m = THGSModel(tpl, THGSConfig(), audio_dim=8)
    g = m.gaussians
    g.parent = g.parent.clone()
    g.parent[[3, 5]] = 7  # vertices 3 and 5 lose their Gaussian to vertex 7
    a, b = m.gaussians_of([7, 2])
    assert a.tolist() == [3, 5, 7] and b.tolist() == [2]
    with pytest.raises(AvatarError, match="no Gaussian is bound"):
        m.gaussians_of([2, 3])


def test_rotating_one_joint_rotates_exactly_its_gaussians():
    t = _two_cluster_template()
    skin = VoxelSkinning(t.V, t.weights, res=32)
    X = torch.tensor(t.V, dtype=torch.float32)
    W = skin(X)
    assert torch.allclose(W[:200, 0], torch.ones(200)) and torch.allclose(W[200:, 1], torch.ones(200))
    rot = torch.zeros(2, 3)
    rot[1] = torch.tensor([0.0, 0.0, math.pi / 2])
    A = joint_transforms(torch.tensor(t.joints, dtype=torch.float32), t.parents, rot)
    q = torch.tensor([[1.0, 0, 0, 0]]).repeat(400, 1)
    Xp, qp = lbs(X, q, W, A)
    Rz = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    j1 = torch.tensor([0.0, 1, 0])
    assert torch.allclose(Xp[:200], X[:200], atol=1e-6)  # the other joint's Gaussians stay
    assert torch.allclose(Xp[200:], (X[200:] - j1) @ Rz.T + j1, atol=1e-5)
    s = math.sqrt(0.5)
    assert torch.allclose(qp[200:], torch.tensor([s, 0, 0, s]).expand(200, 4), atol=1e-5)
    assert torch.allclose(qp[:200], q[:200], atol=1e-6)


def test_parent_rotation_carries_the_child_joint():
    joints = torch.tensor([[0.0, 0, 0], [0, 1, 0], [0, 2, 0]])
    rot = torch.zeros(3, 3)
    rot[0, 2] = math.pi / 2
    A = joint_transforms(joints, [-1, 0, 1], rot, torch.tensor([1.0, 0, 0]))
    tip = torch.tensor([0.0, 2, 0, 1])
    assert torch.allclose((A[2] @ tip)[:3], torch.tensor([1 - 2.0, 0, 0]), atol=1e-6)


def test_voxel_skinning_agrees_with_vertex_weights_at_the_vertices(tpl):
    skin = VoxelSkinning(tpl.V, tpl.weights, res=64)
    W = skin(torch.tensor(tpl.V, dtype=torch.float32)).detach().numpy()
    err = np.abs(W - tpl.weights).sum(1)
    assert np.allclose(W.sum(1), 1, atol=1e-5)
    assert err.mean() < 0.02 and np.percentile(err, 99) < 0.15
    # a coarse grid is measurably worse: the test would catch a wrong lookup
    coarse = VoxelSkinning(tpl.V, tpl.weights, res=6)(torch.tensor(tpl.V, dtype=torch.float32)).detach().numpy()
    assert np.abs(coarse - tpl.weights).sum(1).mean() > 2 * err.mean()


def test_leb_with_zero_delta_equals_the_base_and_stays_in_the_head(tpl):
    leb = ExpressionBlendshapes(tpl.expr_basis, tpl.head_mask)
    psi = torch.rand(tpl.n_expr)
    base = torch.einsum("k,knc->nc", psi, torch.tensor(tpl.expr_basis, dtype=torch.float32))
    assert torch.allclose(leb(psi), base, atol=1e-7)
    with torch.no_grad():
        leb.delta.add_(0.01)
    D = leb(psi) - base
    head = torch.tensor(tpl.head_mask)
    assert torch.allclose(D[~head], torch.zeros_like(D[~head]), atol=1e-7)
    assert float(D[head].detach().abs().min()) > 0
    assert float(leb.penalty().detach()) > 0


def test_saam_with_zero_audio_moves_nothing(tpl):
    saam = SpatialAudioAttention(tpl.mouth_box, audio_dim=16)
    X = torch.tensor(tpl.V[:50], dtype=torch.float32)
    a = torch.randn(16)
    assert torch.equal(saam(X, a), torch.zeros(50, 10))  # zero-initialised output layer
    with torch.no_grad():
        for p in saam.mlp.parameters():
            p.add_(torch.randn_like(p) * 0.1)
    assert torch.allclose(saam(X, torch.zeros(16)), torch.zeros(50, 10), atol=1e-7)
    assert float(saam(X, a).detach().abs().max()) > 1e-4


def test_log_mel_peaks_at_the_tone_and_frames_follow_loudness(tmp_path):
    from scipy.io import wavfile

    sr = 16000
    t = np.arange(sr) / sr
    tone = np.sin(2 * np.pi * 1000 * t)
    S, hop = log_mel(tone, sr, n_mels=40)
    assert hop == 0.01 and S.shape[1] == 40
    mel = lambda f: 2595 * np.log10(1 + f / 700)  # noqa: E731
    centres = np.linspace(mel(50), mel(8000), 42)[1:-1]
    assert abs(int(np.argmax(S.mean(0))) - int(np.argmin(np.abs(centres - mel(1000))))) <= 1
    x = np.concatenate([np.zeros(sr // 2), 0.5 * tone[: sr // 2]])
    wavfile.write(tmp_path / "a.wav", sr, (x * 32767).astype(np.int16))
    A = audio_features(tmp_path / "a.wav", 25, 25.0)
    assert A.shape == (25, 40)
    assert A[18:].mean() > A[:10].mean() + 5  # the loud half has more energy
    env = envelope(x, sr, 25.0, 25)
    assert env[:12].max() < 1e-6 and env[14:].min() > 0.3
    np.save(tmp_path / "f.npy", np.arange(20, dtype=np.float32).reshape(10, 2))
    B = audio_features(tmp_path / "f.npy", 19, 25.0)
    assert B.shape == (19, 2) and np.isclose(B[-1, 1], 19.0)
    (tmp_path / "bad.wav").write_bytes(b"RIFF0000")
    with pytest.raises(AvatarError):
        audio_features(tmp_path / "bad.wav", 5, 25.0)


def test_smplx_loader_on_a_small_file_in_the_same_format(tmp_path):
    rng = np.random.default_rng(0)
    n, J, E = 60, 25, 5
    V = rng.normal(size=(n, 3))
    Jreg = rng.random((J, n))
    Jreg /= Jreg.sum(1, keepdims=True)
    W = rng.random((n, J))
    W /= W.sum(1, keepdims=True)
    W[:10] = 0
    W[:10, 22] = 1  # jaw
    kin = np.stack([np.r_[4294967295, np.arange(J - 1)], np.arange(J)]).astype(np.int64)
    sd = rng.normal(size=(n, 3, 300 + E))
    np.savez(tmp_path / "SMPLX_TEST.npz", v_template=V, f=np.array([[0, 1, 2], [1, 2, 3]]), J_regressor=Jreg,
             kintree_table=kin, weights=W, shapedirs=sd)
    t = load_smplx(tmp_path / "SMPLX_TEST.npz", n_expr=E)
    assert np.allclose(t.joints, Jreg @ V)
    assert t.parents[0] == -1 and list(t.parents[1:]) == list(range(J - 1))
    assert np.allclose(t.expr_basis, np.moveaxis(sd[:, :, 300:], 2, 0))
    assert t.jaw == 22
    with pytest.raises(AvatarError, match="pickle"):
        load_smplx(tmp_path / "SMPLX.pkl")
    np.savez(tmp_path / "broken.npz", v_template=V)
    with pytest.raises(AvatarError):
        load_smplx(tmp_path / "broken.npz")


def test_template_validation_and_round_trip(tpl, tmp_path):
    tpl.save(tmp_path / "t.npz")
    t2 = Template.load(tmp_path / "t.npz")
    assert np.array_equal(t2.F, tpl.F) and t2.joint_names == tpl.joint_names and t2.jaw == tpl.jaw
    bad = tpl.weights.copy()
    bad[0] *= 2
    with pytest.raises(AvatarError, match="sum to 1"):
        Template(tpl.V, tpl.F, tpl.joints, tpl.parents, bad, tpl.expr_basis, tpl.head_mask, tpl.mouth_box,
                 tpl.joint_names)
    assert np.allclose(tpl.weights.sum(1), 1)
    assert tpl.weights[:, tpl.jaw].max() > 0.9  # the jaw is skinned to its joint


def test_mouth_openness_measures_a_dark_cavity():
    img = np.full((20, 20, 3), 0.6, np.float32)
    assert mouth_openness(img, (0, 20, 0, 20)) == 0.0
    img[8:12, 5:15] = 0.05
    assert math.isclose(mouth_openness(img, (0, 20, 0, 20)), 40 / 400)


def test_audio_articulation_drives_only_the_untracked_dofs(tpl):
    """Silence moves nothing for any weights; with audio, the untracked jaw and expression move
    and the tracked ones stay exactly as given; an avatar without it ignores the audio there."""
    art = AudioArticulation(8, 4, 3)
    a = torch.randn(8)
    dr, de = art(a)
    assert dr.shape == (4, 3) and de.shape == (3,) and not dr.any() and not de.any()  # zero last layer
    with torch.no_grad():
        for p in art.mlp.parameters():
            p.add_(torch.randn_like(p) * 0.3)
    z = art(torch.zeros(8))
    assert torch.allclose(z[0], torch.zeros(4, 3), atol=1e-7) and torch.allclose(z[1], torch.zeros(3), atol=1e-7)
    J, K = len(tpl.joints), tpl.n_expr
    m = THGSModel(tpl, THGSConfig(use_saam=False, audio_window=0), audio_dim=8)
    with torch.no_grad():
        for p in m.artic.mlp.parameters():
            p.add_(torch.randn_like(p) * 0.3)
        m.tracked_joints[:] = True
        m.tracked_joints[tpl.jaw] = False
        m.tracked_expr[:] = True
        m.tracked_expr[0] = False
    rot, transl, expr = np.zeros((J, 3)), np.zeros(3), np.zeros(K)
    with torch.no_grad():
        silent = m(rot, transl, expr, torch.zeros(8)).means
        moved = m(rot, transl, expr, a).means
        jaw_w = m.skin(m.gaussians.means)[:, tpl.jaw]
        m.tracked_joints[tpl.jaw] = True  # everything tracked: the audio moves nothing
        m.tracked_expr[0] = True
        tracked = m(rot, transl, expr, a).means
    assert torch.allclose(silent, m.gaussians.means, atol=1e-6) and torch.equal(tracked, silent)
    d = (moved - silent).norm(dim=1)
    assert float(d.max()) > 1e-5
    m2 = THGSModel(tpl, THGSConfig(use_saam=False, audio_window=0), audio_dim=8)  # the jaw alone untracked
    m2.load_state_dict(m.state_dict())
    with torch.no_grad():
        m2.tracked_joints[tpl.jaw] = False
        d2 = (m2(rot, transl, expr, a).means - silent).norm(dim=1)
    assert float(d2[jaw_w > 0.05].max()) > 1e-5 and float(d2[jaw_w == 0].abs().max()) < 1e-7
    off = THGSModel(tpl, THGSConfig(use_saam=False, use_audio_pose=False), audio_dim=8)
    assert off.artic is None
    # a model saved before the option existed has no articulation
    assert THGSConfig.from_dict({"iters": 10}).use_audio_pose is False


@pytest.fixture(scope="module")
def talk_dir(tmp_path_factory):
    from geoface.thgs.data import make_synthetic_talking

    return make_synthetic_talking(tmp_path_factory.mktemp("talk") / "d", seconds=2.0, res=64, n_vertices=2000,
                                  quiet=True)


def test_synthetic_talking_mouth_follows_the_speech(talk_dir):
    from geoface.thgs.data import load_talking

    d = load_talking(talk_dir)
    assert len(d) == 50 and d.audio.shape == (50, 40) and d.rot.shape == (50, 4, 3)
    jaw = np.array(d.meta["jaw_open"])
    loud = d.audio.mean(1)
    assert np.corrcoef(jaw, loud)[0, 1] > 0.5  # the jaw opens with the sound (lag 40 ms)
    assert not np.abs(d.rot[:, 3]).any()  # the tracker's poses leave the jaw to the audio


def test_a_few_training_steps_lower_the_loss_and_round_trip(talk_dir, tmp_path):
    cfg = THGSConfig(iters=40, stage_scale=0.0005)
    info = train_thgs(talk_dir, tmp_path / "m", cfg, progress=False)
    h = [r["loss"] for r in info["history"]]
    assert np.mean(h[-10:]) < 0.8 * np.mean(h[:10])
    assert info["history"][-1]["stage"] == 4
    m = load_thgs(tmp_path / "m")
    from geoface.thgs.data import load_talking

    d = load_talking(talk_dir)
    # the tracker measured neither the jaw nor the pucker: those get no per-frame correction
    # (they would fit each training frame's mouth and leave the audio module nothing to learn)
    assert not d.tracked_joints[d.template.jaw] and d.tracked_joints.sum() == len(d.template.joints) - 1
    pk = [i for i, t in enumerate(d.tracked_expr) if not t]
    assert len(pk) == 1
    assert torch.count_nonzero(m.d_rot[:, d.template.jaw]) == 0 and torch.count_nonzero(m.d_expr[:, pk]) == 0
    assert torch.count_nonzero(m.d_rot[:, d.tracked_joints]) > 0  # the tracked ones are corrected
    # the saved avatar knows what was tracked: the audio drives the rest at animation time
    assert torch.equal(m.tracked_joints, torch.as_tensor(d.tracked_joints)) and m.artic is not None
    assert float(m.artic.mlp[-1].weight.detach().abs().max()) > 0  # it learned something from the audio
    ev = evaluate_thgs(m, d)
    assert ev["frames"] == 10 and 5 < ev["psnr"] < 60 and -1 <= ev["lipsync_corr"] <= 1
    (tmp_path / "m" / "model.safetensors").write_bytes(b"junk")
    with pytest.raises(AvatarError):
        load_thgs(tmp_path / "m")


def test_cli(talk_dir, tmp_path, capsys):
    from geoface.cli import main

    md = tmp_path / "m"
    assert main(["talk", "train", str(talk_dir), "-o", str(md), "--iters", "3", "-q"]) == 0
    assert main(["talk", "train", str(talk_dir), "-o", str(md), "--iters", "3", "-q"]) == 2
    assert json.loads((md / "config.json").read_text())["config"]["artic_prefit"] is False
    assert main(["talk", "train", str(talk_dir), "-o", str(tmp_path / "pf"), "--iters", "3", "-q", "--prefit"]) == 0
    assert json.loads((tmp_path / "pf" / "config.json").read_text())["config"]["artic_prefit"] is True
    assert main(["talk", "animate", str(md), "--audio", str(talk_dir / "audio.wav"), "-o", str(tmp_path / "o")]) == 0
    assert len(list((tmp_path / "o" / "frames").glob("*.png"))) == 50
    assert main(["talk", "eval", str(md), str(talk_dir), "--json", str(tmp_path / "e.json")]) == 0
    assert "lipsync_corr" in json.loads((tmp_path / "e.json").read_text())
    # a video with the speech: the right frame count and duration, and an audio stream
    pytest.importorskip("imageio_ffmpeg")
    from geoface.video import probe_video

    mp4 = tmp_path / "talk.mp4"
    assert main(["talk", "animate", str(md), "--audio", str(talk_dir / "audio.wav"), "--video", str(mp4)]) == 0
    v = probe_video(mp4)
    assert v["frames"] == 50 and abs(v["seconds"] - 2.0) < 0.05 and v["fps"] == 25 and v["codec"] == "h264"
    assert v["audio"] and v["audio_codec"] == "aac" and abs(v["duration"] - 2.0) < 0.1
    assert main(["talk", "animate", str(md), "--audio", str(talk_dir / "audio.wav"), "--video", str(mp4)]) == 2  # exists
    assert main(["talk", "animate", str(md), "--audio", str(talk_dir / "audio.wav")]) == 2  # nowhere to write
    # a video's sound drives it too (the same speech: the same 50 frames); a silent video is refused
    assert main(["talk", "animate", str(md), "--audio", str(mp4), "-o", str(tmp_path / "ov"), "-q"]) == 0
    assert len(list((tmp_path / "ov" / "frames").glob("*.png"))) == 50
    from geoface.video import write_video

    write_video(np.zeros((5, 32, 32, 3), np.uint8), tmp_path / "silent.mp4", fps=5)
    capsys.readouterr()
    assert main(["talk", "animate", str(md), "--audio", str(tmp_path / "silent.mp4"), "-o", str(tmp_path / "os")]) == 2
    assert "no sound" in capsys.readouterr().err and not (tmp_path / "os").exists()
    # export: standard 3DGS PLY files that load back with the avatar's Gaussians
    from geoface.drive.avatars import avatar_drive
    from geoface.splat.ply import load_ply

    assert main(["talk", "export", str(md), "-o", str(tmp_path / "rest.ply")]) == 0
    assert main(["talk", "export", str(md), "--drive", str(talk_dir), "--frames", "0:50:10", "-o", str(tmp_path / "seq")]) == 0
    files = sorted((tmp_path / "seq").glob("frame_*.ply"))
    assert [f.name for f in files] == [f"frame_{t:05d}.ply" for t in range(0, 50, 10)]
    drive = avatar_drive(md, talk_dir)
    assert drive.n_frames == 50 and drive.frames.shape[0] == 50
    g20, back = drive.gaussians(20), load_ply(files[2])
    assert torch.allclose(back.means, g20.means, atol=1e-5) and torch.allclose(back.log_scales, g20.log_scales, atol=1e-5)
    assert torch.allclose(back.opacity_logits, g20.opacity_logits, atol=1e-5)
    assert not torch.allclose(load_ply(files[0]).means, back.means)  # the frames differ: the avatar moves
    assert main(["talk", "export", str(md), "--frames", "7", "-o", str(tmp_path / "x.ply")]) == 2  # rest pose: 1 frame
    if importlib.util.find_spec("viser"):  # the web viewer serves the animated avatar beside its video
        import socket

        from geoface.webview import WebView

        with socket.socket() as sk:
            sk.bind(("127.0.0.1", 0))
            port = sk.getsockname()[1]
        view = WebView([md], drive=talk_dir, port=port, quiet=True)
        try:
            it = view.items[0]
            assert it.kind == "avatar" and it.extra["drive"].n_frames == 50 and it.extra["drive"].frames is not None
            assert view.url == f"http://127.0.0.1:{port}"
        finally:
            view.stop()
    assert main(["talk", "animate", str(md), "--audio", str(tmp_path / "none.wav"), "-o", str(tmp_path / "o2")]) == 2
    assert main(["talk", "train", str(tmp_path), "-o", str(tmp_path / "m2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("geoface: error:") for line in err)
    assert not (tmp_path / "o2").exists() and not (tmp_path / "m2").exists()


def test_frame_corrections_move_only_the_drawn_frame_by_its_gradient():
    """Only the drawn frame's row moves; its first step is the rate (the gradient over its own
    root-mean-square); a tensor that gets gradients later debiases by its own count."""
    from geoface.avatar.corrections import FrameCorrections

    a = torch.nn.Parameter(torch.zeros(5, 3))
    b = torch.nn.Parameter(torch.zeros(5, 2))
    opt = FrameCorrections([(a, 0.1), (b, 0.01)])
    for _ in range(3):  # b gets no gradient yet
        a.grad = torch.zeros(5, 3)
        a.grad[2] = torch.tensor([1.0, -2.0, 0.5])
        opt.step(2)
        opt.zero_grad()
    assert torch.count_nonzero(a[[0, 1, 3, 4]]) == 0 and torch.count_nonzero(b) == 0
    # a steady gradient: each step is the rate, against the gradient's sign
    torch.testing.assert_close(a[2].detach(), torch.tensor([-0.3, 0.3, -0.3]))
    b.grad = torch.zeros(5, 2)
    b.grad[4] = torch.tensor([3.0, -3.0])
    opt.step(4)
    torch.testing.assert_close(b[4].detach(), torch.tensor([-0.01, 0.01]))  # first step = the rate exactly
    c = torch.nn.Parameter(torch.zeros(4, 3, 2))  # rows of 3 joints × 2; joint 1 is not to be corrected
    opt = FrameCorrections([(c, 0.1, torch.tensor([True, False, True])[:, None])])
    for r in range(4):
        c.grad = torch.ones(4, 3, 2)
        opt.step(r)
    assert torch.count_nonzero(c[:, 1]) == 0 and bool((c[:, [0, 2]] == -0.1).all())


def test_tracked_masks_default_to_all_and_reject_bad_shapes(tmp_path):
    from geoface.thgs.data import load_tracked

    p = tmp_path / "poses.npz"
    np.savez(p, rot=np.zeros((2, 4, 3)), transl=np.zeros((2, 3)), expr=np.zeros((2, 5)))
    tj, te = load_tracked(p, 4, 5)
    assert tj.all() and te.all() and tj.shape == (4,) and te.shape == (5,)
    for bad in ({"tracked_joints": np.ones(3, bool)}, {"tracked_expr": np.ones(5, np.int64)}):
        np.savez(p, rot=np.zeros((2, 4, 3)), transl=np.zeros((2, 3)), expr=np.zeros((2, 5)), **bad)
        with pytest.raises(AvatarError, match="tracked_"):
            load_tracked(p, 4, 5)


def test_audio_context_stacks_the_neighbouring_frames_and_repeats_the_ends():
    from geoface.avatar.audio import audio_context

    A = np.arange(12, dtype=np.float32).reshape(4, 3)
    C = audio_context(A, 1)
    assert C.shape == (4, 9)
    assert np.array_equal(C[1], np.r_[A[0], A[1], A[2]]) and np.array_equal(C[0], np.r_[A[0], A[0], A[1]])
    assert np.array_equal(C[3], np.r_[A[2], A[3], A[3]])
    assert np.array_equal(audio_context(A, 0), A)
    with pytest.raises(AvatarError):
        audio_context(A, -1)
    with pytest.raises(AvatarError):
        audio_context(A[0], 1)


def test_audio_window_trains_saves_and_drives_with_the_neighbouring_frames(talk_dir, tmp_path):
    """With ``audio_window`` the networks read 2 W + 1 frames of features; the folder keeps the
    per-frame count, so the same WAV or features drive it, and a frame's neighbours change it."""
    from geoface.thgs.inference import render_frames
    from geoface.thgs.data import load_talking

    cfg = THGSConfig(iters=30, stage_scale=0.0004, audio_window=2)
    train_thgs(talk_dir, tmp_path / "m", cfg, progress=False)
    m = load_thgs(tmp_path / "m")
    d = load_talking(talk_dir)
    assert m.cfg.audio_window == 2 and m.audio_dim == 40 and m.audio_ref.shape == (200,)
    assert m.artic.mlp[0].in_features == 200 and float(m.artic.mlp[-1].weight.detach().abs().max()) > 0
    A = m.audio_input(d.audio)
    assert A.shape == (50, 200) and torch.equal(A[10, 80:120], torch.as_tensor(d.audio[10]))
    # frame 10 rendered from the whole sequence, then with its neighbours' sound silenced
    r0 = render_frames(m, d.camera, d.rot, d.transl, d.expr, d.audio, frames=[10])[0]
    quiet = d.audio.copy()
    quiet[[8, 9, 11, 12]] = d.audio.min(0)
    r1 = render_frames(m, d.camera, d.rot, d.transl, d.expr, quiet, frames=[10])[0]
    assert np.abs(r0 - r1).max() > 1e-4
    ev = evaluate_thgs(m, d)
    assert 5 < ev["psnr"] < 60
    with pytest.raises(AvatarError, match="audio_window must be >= 0"):
        THGSConfig(audio_window=-1)
    # the default reads two frames each side; a folder saved before the option read one frame
    assert THGSConfig().audio_window == 2 and THGSConfig.from_dict({}).audio_window == 0


def test_pose_decay_lets_the_corrections_settle_and_is_checked(talk_dir, tmp_path):
    # the same training with the corrections' rate falling 100-fold: the last visits barely move them
    from geoface.thgs.data import load_talking

    got = {}
    for decay in (1.0, 100.0):
        cfg = THGSConfig(iters=30, stage_scale=0.0005, pose_decay=decay, lr_pose=0.02)
        train_thgs(talk_dir, tmp_path / f"m{decay}", cfg, progress=False)
        got[decay] = load_thgs(tmp_path / f"m{decay}").d_rot.detach()
    d = load_talking(talk_dir)
    tr = slice(0, 40)
    size = {k: float(v[tr][:, d.tracked_joints].abs().mean()) for k, v in got.items()}
    assert size[100.0] < 0.6 * size[1.0] and size[100.0] > 0
    with pytest.raises(AvatarError, match="pose_decay"):
        THGSConfig(pose_decay=0.5)
    assert THGSConfig.from_dict({"iters": 10}).pose_decay == 1.0  # folders saved before the option


def test_device_cuda_without_a_gpu_is_one_line(talk_dir, tmp_path, monkeypatch, capsys):
    from geoface.cli import main

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(AvatarError, match="no CUDA"):
        train_thgs(talk_dir, tmp_path / "m", THGSConfig(iters=2), progress=False, device="cuda")
    assert main(["talk", "train", str(talk_dir), "-o", str(tmp_path / "m"), "--iters", "2", "--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "CUDA" in err[0]
    assert not (tmp_path / "m" / "model.safetensors").exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_training_on_the_gpu_saves_a_cpu_model_that_renders_alike(talk_dir, tmp_path):
    cfg = THGSConfig(iters=40, stage_scale=0.0005)
    info = train_thgs(talk_dir, tmp_path / "m", cfg, progress=False, device="cuda")
    h = [r["loss"] for r in info["history"]]
    assert np.mean(h[-10:]) < 0.8 * np.mean(h[:10])
    m = load_thgs(tmp_path / "m")
    assert all(p.device.type == "cpu" for p in m.parameters())
    from geoface.thgs.data import load_talking

    ev = evaluate_thgs(m, load_talking(talk_dir))
    assert 5 < ev["psnr"] < 60
    ref = tmp_path / "cpu"
    train_thgs(talk_dir, ref, cfg, progress=False)
    assert abs(ev["psnr"] - evaluate_thgs(load_thgs(ref), load_talking(talk_dir))["psnr"]) < 2.0
