"""Usage poses aligned with the image (geoface.hfm.align): frames the avatar itself rendered
in known poses are the known answer."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from geoface.avatar.corrections import corrected_pose
from geoface.errors import AvatarError
from geoface.hfm import HFMConfig, load_hfm, save_hfm, train_hfm
from geoface.hfm.align import align_poses
from geoface.hfm.data import frame_input, load_video
from geoface.splat.rasterizer import rasterize


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A briefly trained model (an ICT-FaceKit capture, poses from its landmarks) and a usage video whose frames are that model's own renders in the
    video's true poses (so the true poses are exactly right)."""
    from geoface.hfm.ict import make_ict_hmd

    out = tmp_path_factory.mktemp("align")
    reg, use = make_ict_hmd(out, frames=12, usage_frames=3, res=64, seed=5, gaussians=800, map_res=128, supersample=1,
                            quiet=True)
    cfg = HFMConfig(iters=30, warmup=0.1, densify=False, seed=0, n_keys=128, crop=64)
    train_hfm(reg, out / "m", cfg, progress=False, log=None, poses="landmarks")
    model = load_hfm(out / "m")
    video = load_video(use)
    R, t, p = video.poses
    boxes = video.boxes()
    with torch.no_grad():
        frames = np.stack([rasterize(model(*frame_input(video, f, model.cfg.crop, boxes), (R[f], t[f], p)),
                                     video.camera, background=torch.zeros(3))[0].clamp(0, 1).numpy()
                           for f in range(len(video))])
    return model, replace(video, frames=frames), use


def _angles(Ra, Rb) -> np.ndarray:
    return np.degrees(np.linalg.norm(Rotation.from_matrix(np.transpose(Ra, (0, 2, 1)) @ Rb).as_rotvec(), axis=1))


def test_a_tilted_pose_comes_back_to_the_rendered_one(rendered):
    model, video, _ = rendered
    R, t, p = video.poses
    tilt = torch.tensor(np.radians([1.5, 0.0, 0.0]), dtype=torch.float32)  # pitch about the head's centre
    Rw, tw = (np.stack(a) for a in zip(*[[x.double().numpy() for x in corrected_pose(
        torch.tensor(R[f], dtype=torch.float32), torch.tensor(t[f], dtype=torch.float32),
        torch.tensor(p, dtype=torch.float32), tilt, torch.zeros(3), model.center)[:2]] for f in range(len(R))]))
    assert np.allclose(_angles(R, Rw), 1.5, atol=1e-3)
    Ra, ta, pa = align_poses(model, video, (Rw, tw, p), steps=60, lr=3e-3, smooth=0)
    err = _angles(R, Ra)
    assert err.max() < 0.5 and err.mean() < 0.35, err
    assert np.array_equal(pa, p)
    # rotation only: the translation moves only as the rotation about the head's centre moves it
    moved = np.linalg.norm(ta - t, axis=1)
    assert moved.max() < 0.1 * float(model.scale)


def test_translation_is_learned_only_when_asked_and_smoothing_keeps_a_constant(rendered):
    model, video, _ = rendered
    R, t, p = video.poses
    shift = np.array([0.0, 0.004, 0.0])  # 4 mm up
    Ra, ta, _ = align_poses(model, video, (R, t + shift, p), steps=60, lr=3e-3, translation=True, smooth=0)
    before = np.linalg.norm(shift)
    after = np.linalg.norm(ta - t, axis=1)
    assert after.mean() < 0.5 * before, after
    # exact poses stay put (a constant correction of zero survives smoothing)
    Rz, tz, _ = align_poses(model, video, (R, t, p), steps=10, lr=1e-3, smooth=1.5)
    assert _angles(R, Rz).max() < 0.2 and np.abs(tz - t).max() < 1e-3


def test_errors(rendered):
    model, video, _ = rendered
    with pytest.raises(AvatarError, match="hmd_masks"):
        align_poses(model, replace(video, hmd_masks=None), video.poses)
    with pytest.raises(AvatarError, match="steps"):
        align_poses(model, video, video.poses, steps=0)


def test_cli_aligns_landmark_poses_on_request(rendered, tmp_path, capsys):
    from geoface.cli import main

    model, _, use = rendered
    md = tmp_path / "m"
    save_hfm(model, md)
    args = ["hmd", "eval", str(md), str(use), "--poses", "landmarks", "--json"]
    assert main(args + [str(tmp_path / "a.json"), "--pose-align", "2"]) == 0
    assert json.loads((tmp_path / "a.json").read_text())["poses"] == "landmarks+image"
    assert main(args + [str(tmp_path / "b.json")]) == 0  # the model's setting: not aligned
    assert json.loads((tmp_path / "b.json").read_text())["poses"] == "landmarks"
    assert main(args + [str(tmp_path / "c.json"), "--pose-align", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("geoface: error: --pose-align") and not (tmp_path / "c.json").exists()


def test_the_model_is_left_untouched(rendered):
    model, video, _ = rendered
    before = {k: v.clone() for k, v in model.state_dict().items()}
    align_poses(model, video, video.poses, steps=2)
    assert all(p.grad is None for p in model.parameters())
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())
