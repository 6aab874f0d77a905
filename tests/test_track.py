"""geoface track: MediaPipe's face mesh and selfie segmentation turn a capture's frames into the
68 iBUG landmarks and person masks that the avatars read, measured against the renderer's truth."""
from __future__ import annotations

import json

import numpy as np
import pytest

from geoface.track import ibug68_from_mediapipe


def test_the_landmark_table_is_a_convex_combination_per_landmark():
    idx, w = ibug68_from_mediapipe()
    assert idx.shape[0] == 68 and idx.shape == w.shape and (0 <= idx).all() and (idx < 468).all()
    assert np.allclose(w.sum(1), 1.0)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    pytest.importorskip("mediapipe")
    from geoface.hfm.ict import make_ict_hmd

    reg, _ = make_ict_hmd(tmp_path_factory.mktemp("cap") / "c", frames=6, usage_frames=2, res=256, seed=11, quiet=True)
    return reg


def test_tracked_landmarks_and_masks_match_the_truth(capture, tmp_path, capsys):
    from geoface.avatar.capture import read_landmarks
    from geoface.cli import main
    from geoface.images import read_image

    # one frame without a face: found False there, its landmarks interpolated from its neighbours
    black = capture.parent / "with_black"
    import shutil

    shutil.copytree(capture, black)
    frames = sorted((black / "frames").glob("*.png"))
    from geoface.images import save_image

    save_image(frames[2], np.zeros((256, 256, 3)))
    out = tmp_path / "tracked"
    assert main(["track", str(black), "-o", str(out), "-q"]) == 0
    assert "landmarks on 5 of 6 frames (1 interpolated)" in capsys.readouterr().out
    doc = json.loads((out / "landmarks.json").read_text())
    assert doc["tracker"] == "mediapipe-facemesh" and doc["found"] == [True, True, False, True, True, True]
    true, names = read_landmarks(capture / "landmarks.json", 6)
    got, got_names = read_landmarks(out / "landmarks.json", 6)
    assert got_names == names
    err = np.linalg.norm(got - true, axis=-1)
    ok = np.array(doc["found"])
    iod = np.linalg.norm(true[:, 36] - true[:, 45], axis=-1).mean()
    assert err[ok].mean() < 0.06 * iod, (err[ok].mean(), iod)  # a tracker's error, not a wrong table (~0.5 iod)
    assert np.isfinite(got[2]).all() and err[2].mean() < 0.25 * iod  # interpolated between frames 1 and 3
    for f in sorted((out / "frames").glob("*.png"))[:2]:
        m = read_image(out / "masks" / f.name, "gray") > 0.5
        t = read_image(capture / "masks" / f.name, "gray") > 0.5
        assert (m & t).sum() / (m | t).sum() > 0.8  # the segmentation covers the rendered person
    assert (out / "camera.json").is_file() and (out / "head.ply").is_file()
    assert main(["track", str(black), "-o", str(out), "-q"]) == 2  # exists: refused without --force
