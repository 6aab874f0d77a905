"""geoface track: MediaPipe's face mesh and selfie segmentation turn a capture's frames into the
68 iBUG landmarks and person masks that the avatars read, measured against the renderer's truth."""
from __future__ import annotations

import json

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.track import headset_masks, ibug68_from_mediapipe


def test_the_landmark_table_is_a_convex_combination_per_landmark():
    idx, w = ibug68_from_mediapipe()
    assert idx.shape[0] == 68 and idx.shape == w.shape and (0 <= idx).all() and (idx < 468).all()
    assert np.allclose(w.sum(1), 1.0)


def test_mediapipe_starts_without_pyplot_and_its_drawing_helpers_still_draw():
    """MediaPipe imports matplotlib.pyplot on start (most of its import time); geoface defers it:
    after the tracker loads, pyplot is not loaded, MediaPipe's drawing helper reaches the real
    pyplot when used, and a later ``import matplotlib.pyplot`` is the real module. A process that
    loaded pyplot first keeps its own."""
    import subprocess
    import sys

    pytest.importorskip("mediapipe")
    code = """
import sys, types
from geoface.track import load_mediapipe
mp = load_mediapipe()
assert "matplotlib.pyplot" not in sys.modules and "matplotlib" not in sys.modules, sorted(m for m in sys.modules if "matplotlib" in m)
figure = mp.solutions.drawing_utils.plt.figure
import matplotlib
import matplotlib.pyplot as plt
assert figure is plt.figure and matplotlib.pyplot is plt and type(plt) is types.ModuleType
assert type(matplotlib) is types.ModuleType and callable(plt.subplots)
"""
    first = """
import matplotlib.pyplot as plt
from geoface.track import load_mediapipe
mp = load_mediapipe()
assert mp.solutions.drawing_utils.plt is plt
"""
    for src in (code, first):
        r = subprocess.run([sys.executable, "-c", src], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[-2000:]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    pytest.importorskip("mediapipe")
    from geoface.hfm.ict import make_ict_hmd

    reg, _ = make_ict_hmd(tmp_path_factory.mktemp("cap") / "c", frames=6, usage_frames=2, res=256, seed=11, quiet=True)
    return reg


def test_headset_masks_find_a_grey_box_on_a_face_and_nothing_on_skin():
    rng = np.random.default_rng(0)
    img = np.zeros((3, 96, 96, 3), np.uint8)                      # black background
    yy, xx = np.mgrid[:96, :96]
    face = (yy - 50) ** 2 / 40 ** 2 + (xx - 48) ** 2 / 30 ** 2 < 1  # a skin-coloured ellipse
    img[:, face] = (205, 150, 120)
    box = (yy >= 25) & (yy < 48) & (xx >= 16) & (xx < 80)          # a grey headset over the eyes
    img[0, box], img[1, box] = (70, 72, 75), (30, 30, 32)          # grey, then near-black plastic
    img[:2, 30:34, 30:40] = (205, 150, 120)                        # a hole in it (a reflection) is filled
    img[:2] = np.clip(img[:2].astype(int) + rng.integers(-4, 5, img[:2].shape), 0, 255).astype(np.uint8)
    img[0, 5:8, 5:8] = (90, 90, 90)                                # a grey speck elsewhere is not the headset
    m = headset_masks(img)
    assert m.shape == (3, 96, 96) and m.dtype == bool
    for t in (0, 1):
        iou = (m[t] & box).sum() / (m[t] | box).sum()
        assert iou > 0.95, (t, iou)
    assert not m[0, 5:8, 5:8].any()
    assert not m[2].any()                                         # no headset: an empty mask
    with pytest.raises(GeofaceError, match="RGB"):
        headset_masks(np.zeros((1, 8, 8)))
    with pytest.raises(GeofaceError, match="max_saturation"):
        headset_masks(img, max_saturation=1.5)


def test_tracked_usage_has_segmented_headset_masks_and_scores_with_the_true_ones(capture, tmp_path):
    from dataclasses import replace

    from geoface.hfm.data import load_video
    from geoface.hfm.usage import hmd_metrics
    from geoface.track import track_capture

    out = tmp_path / "usage"
    track_capture(capture.parent / "usage", out, quiet=True)
    v = load_video(out)
    assert v.hmd_masks is not None and v.hmd_masks_true is not None
    for seg, true in zip(v.hmd_masks, v.hmd_masks_true):
        assert (seg & true).sum() / (seg | true).sum() > 0.9  # the grey headset, found from the pixels
    # the evaluation scores where the headset truly hides: wrong renders there only, none in the segmented masks
    v = replace(v, hmd_masks=np.zeros_like(v.hmd_masks))
    R = np.where(v.hmd_masks_true[..., None], 1.0 - v.gt, v.gt)
    r = hmd_metrics(R, v)
    assert r["psnr_occluded"] < 10 and r["psnr_face"] < 30
    assert hmd_metrics(v.gt, v)["psnr_occluded"] == float("inf")


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


def test_synth_verbs_track_their_ict_captures_by_default_and_keep_the_truth(tmp_path, capsys):
    pytest.importorskip("mediapipe")
    from geoface.cli import main
    from geoface.track import track_capture

    out = tmp_path / "cap"
    assert main(["hmd", "synth", "-o", str(out), "--head", "ict", "--frames", "5", "--usage-frames", "2", "--res", "256",
                 "--seed", "11", "-q"]) == 0
    assert "tracked by MediaPipe (a face on 7 of 7 frames" in capsys.readouterr().out
    for which in ("registration", "usage"):
        d = out / which
        got, true = (json.loads((d / n).read_text()) for n in ("landmarks.json", "landmarks_true.json"))
        assert got["tracker"] == "mediapipe-facemesh" and "tracker" not in true and got["names"] == true["names"]
        err = np.linalg.norm(np.array(got["points"]) - np.array(true["points"]), axis=-1).mean()
        assert 0.2 < err < 5.0, err  # a tracker's error, neither the truth copied nor a wrong table
        assert (d / "masks_true").is_dir() and len(list((d / "masks").glob("*.png"))) == len(got["points"])
    assert (out / "usage" / "hmd_masks_true").is_dir()
    # tracked again in place: the truth stays the renderer's, not the first tracking
    before = (out / "usage" / "landmarks_true.json").read_text()
    track_capture(out / "usage", out / "usage", keep_originals=True, overwrite=True, quiet=True)
    assert (out / "usage" / "landmarks_true.json").read_text() == before
    oracle = tmp_path / "oracle"
    assert main(["hmd", "synth", "-o", str(oracle), "--head", "ict", "--frames", "5", "--usage-frames", "2", "--res", "64",
                 "--landmarks", "oracle", "-q"]) == 0
    assert "the renderer's (oracle)" in capsys.readouterr().out
    assert not (oracle / "registration" / "landmarks_true.json").exists()
    # the talking capture too: its truth kept beside the tracker's
    talk = tmp_path / "talk"
    assert main(["talk", "synth", "-o", str(talk), "--head", "ict", "--seconds", "0.2", "--res", "128",
                 "--vertices", "1000", "-q"]) == 0
    said = capsys.readouterr().out
    assert "tracked by MediaPipe" in said and (talk / "landmarks_true.json").is_file()
    assert "head poses fitted to them" in said and (talk / "poses_true.npz").is_file()  # what a user has: tracked poses
    # the procedural head's landmarks are not the tracker's 68: a one-line error naming the way out, nothing written
    toy = tmp_path / "toy"
    assert main(["hmd", "synth", "-o", str(toy), "--frames", "6", "--res", "64", "--landmarks", "tracked", "-q"]) == 2
    assert "--landmarks oracle" in capsys.readouterr().err and not toy.exists()


def test_one_euro_stills_jitter_and_follows_fast_motion_without_lag():
    from geoface.track import one_euro

    rng = np.random.default_rng(0)
    T, fps = 200, 25.0
    still = 100 + rng.normal(0, 1.0, (T, 1, 2))
    sm = one_euro(still, fps, min_cutoff=1.0, beta=0.02)
    assert sm[20:].std(0).max() < 0.5 * still[20:].std(0).min()  # jitter of a still point halved and more
    t = np.arange(T) / fps
    ramp = np.zeros((T, 1, 2))
    ramp[:, 0, 0] = 300.0 * t                                     # 300 px/s: a fast turn
    moving = ramp + rng.normal(0, 1.0, ramp.shape)
    lag = np.abs(one_euro(moving, fps, min_cutoff=1.0, beta=0.02) - ramp)[50:, 0, 0].mean()
    fixed = np.abs(one_euro(moving, fps, min_cutoff=1.0, beta=0.0) - ramp)[50:, 0, 0].mean()
    assert lag < 8.0 < 40.0 < fixed, (lag, fixed)                # a fixed low-pass trails by ~50 px
    # causal: frame t does not see later frames; a frame without a face restarts the filter
    assert np.allclose(one_euro(moving[:80], fps, beta=0.05), one_euro(moving, fps, beta=0.05)[:80])
    gap = moving.copy()
    gap[100] = np.nan
    out = one_euro(gap, fps, beta=0.05)
    assert np.isnan(out[100]).all() and np.allclose(out[101], gap[101])
    with pytest.raises(GeofaceError):
        one_euro(still[:, 0], fps)


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    pytest.importorskip("mediapipe")
    import cv2
    from skimage import data

    from geoface.images import save_image

    img = cv2.resize(data.astronaut(), (256, 256), interpolation=cv2.INTER_AREA)
    d = tmp_path_factory.mktemp("astro")
    save_image(d / "astronaut.png", img)
    return d / "astronaut.png", img


def test_track_a_real_photo_and_a_video_of_it(astronaut, tmp_path, capsys):
    """A real photograph (scikit-image's astronaut, public domain): the landmarks sit on her face;
    a video panning over it: the landmarks follow the pan, in the format capture folders read."""
    from geoface.avatar.capture import read_landmarks
    from geoface.cli import main
    from geoface.images import read_image
    from geoface.video import write_video

    photo, img = astronaut
    assert main(["track", str(photo), "-o", str(tmp_path / "lm.json"), "--masks", str(tmp_path / "m"), "-q"]) == 0
    assert "landmarks on 1 of 1 frames; confidence 0.9" in capsys.readouterr().out
    doc = json.loads((tmp_path / "lm.json").read_text())
    pts, names = read_landmarks(tmp_path / "lm.json", 1)
    assert names[36] == "eye_right_0" and doc["found"] == [True] and doc["image_size"] == [256, 256]
    assert doc["confidence"][0] > 0.7 and doc["smoothed"] is False
    # her outer eye corners and nose tip (measured by hand on the 512² photo, halved)
    for k, xy in ((36, (98, 51)), (45, (128, 52)), (30, (113, 64))):
        assert np.linalg.norm(pts[0, k] - xy) < 4.0, (k, pts[0, k])
    m = read_image(tmp_path / "m" / "astronaut.png", "gray") > 0.5
    assert m[60, 113] and not m[10, 250]  # her face is the person's; the sky (top right) is not
    # a video: the photo shifted right by 2 px a frame
    frames = [np.roll(img, 2 * k, axis=1) for k in range(6)]
    write_video(frames, tmp_path / "pan.mp4", fps=10)
    assert main(["track", str(tmp_path / "pan.mp4"), "-o", str(tmp_path / "pan.json"), "--smooth", "-q"]) == 0
    assert "smoothed (One Euro)" in capsys.readouterr().out
    pan, _ = read_landmarks(tmp_path / "pan.json", 6)
    d = json.loads((tmp_path / "pan.json").read_text())
    assert d["fps"] == 10.0 and d["smoothed"] and len(d["frames"]) == 6
    moved = (pan[:, [30, 36, 45], 0] - pan[0, [30, 36, 45], 0]).mean(1)
    assert np.abs(moved - 2 * np.arange(6)).max() < 1.5, moved  # follows the pan, no lag
    # bad inputs: one line, exit 2
    assert main(["track", str(tmp_path / "none.png"), "-o", str(tmp_path / "x.json"), "-q"]) == 2
    assert main(["track", str(photo), "-o", str(tmp_path / "x.txt"), "-q"]) == 2
    assert main(["track", str(photo), "-o", str(tmp_path / "y.json"), "--no-masks", "-q"]) == 2
    assert main(["track", str(photo), "-o", str(tmp_path / "lm.json"), "-q"]) == 2  # exists: not replaced
    (tmp_path / "notes.txt").write_text("hello")
    assert main(["track", str(tmp_path / "notes.txt"), "-o", str(tmp_path / "z.json"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "not an image" in err


def test_head_poses_fitted_to_landmarks_recover_the_true_poses(tmp_path):
    """The renderer's own landmarks (0.5 px of noise) give the head poses back to about a degree;
    the capture's poses are kept as the truth, the expressions untouched."""
    from geoface.avatar.template import Template
    from geoface.thgs.data import fit_head_poses
    from geoface.thgs.eval import head_pose_errors
    from geoface.thgs.ict import make_ict_talking

    d = make_ict_talking(tmp_path / "talk", seconds=0.4, res=128, n_vertices=1500, map_res=128, seed=3, quiet=True)
    with np.load(d / "poses.npz") as z:
        before = {k: z[k] for k in z.files}
    (d / "poses_true.npz").rename(tmp_path / "truth.npz")  # as a user's capture: no truth beside it
    fit = fit_head_poses(d)
    assert fit["frames"] == 10 and fit["rms_px"] < 1.5 and "nose_tip" in fit["names"]
    with np.load(d / "poses.npz") as z, np.load(d / "poses_true.npz") as kept, np.load(tmp_path / "truth.npz") as t:
        assert np.array_equal(kept["rot"], before["rot"]) and np.array_equal(z["expr"], before["expr"])
        assert not np.allclose(z["transl"], before["transl"])  # fitted, not copied
        err = head_pose_errors(Template.load(d / "template.npz"), z["rot"], z["transl"], t["rot"], t["transl"])
    assert err["rot_deg_mean"] < 1.5 and err["mm_mean"] < 6.0, err
