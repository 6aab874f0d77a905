"""The real-clip protocol (geoface.avatar.protocol) on one second of a real clip: the time split,
the headset drawn at the tracked pose, the baselines and the scorer."""
from __future__ import annotations

import json
import wave

import numpy as np
import pytest

from geoface.avatar import protocol as P
from geoface.capture import Capture, read_landmarks
from geoface.errors import CaptureError, GeofaceError


@pytest.fixture(scope="module")
def split(clip_capture, tmp_path_factory):
    r, _ = clip_capture
    return P.split_capture(r.folder, tmp_path_factory.mktemp("split") / "s", quiet=True)


def _seconds(wav):
    with wave.open(str(wav)) as w:
        return w.getnframes() / w.getframerate()


def test_the_split_is_by_time_and_keeps_the_upper_face_out_of_the_test_inputs(split, clip_capture):
    r, _ = clip_capture
    assert (split.n_train, split.n_test) == (24, 6)  # round(30 · 0.8), as THGS holds out
    tr, te = Capture(split.train), Capture(split.test)
    assert len(tr) == 24 and len(te) == 6
    full = Capture(r.folder)
    # the training frames are the first 24 frames, unchanged; gt/ the last 6
    assert np.array_equal(tr.frames()[[0, 23]], full.frames()[[0, 23]])
    assert np.array_equal(te.images("gt", rgb=True), full.frames()[24:])
    R, t, _ = full.head_poses()
    assert np.allclose(te.head_poses()[0], R[24:]) and np.allclose(tr.head_poses()[1], t[:24])
    # the test inputs: the 43 landmarks below a headset, no eye, brow or nose-bridge point; the
    # rest (and the tracked expressions) only in truth/, which the scorer reads
    names = te.landmarks().names
    assert len(names) == 43 and not any(n.startswith(("eye_", "brow_", "nose_bridge")) for n in names)
    assert not te.has("expressions.npz") and not te.has("landmarks_dense.npz")
    assert read_landmarks(split.test / P.TRUTH / "landmarks.json", 6)[0].shape == (6, 68, 2)
    # the sound cut to the same frames
    fps = full.meta()["fps"]
    assert _seconds(split.train / "audio.wav") == pytest.approx(24 / fps, abs=2e-3)
    assert _seconds(split.test / "audio.wav") == pytest.approx(6 / fps, abs=2e-3)
    meta = json.loads((split.test / "meta.json").read_text())
    assert meta["split"] == "test" and meta["split_frames"] == [24, 30] and len(meta["crop_boxes"]) == 6


def test_the_headset_hides_the_eyes_and_not_the_mouth(split):
    """Pixels: the eyes under the headset's mask, dark grey there; the mouth and chin visible and
    the frame untouched off the mask."""
    te = Capture(split.test)
    shown, gt, hmd = te.frames(), te.images("gt", rgb=True), te.images("hmd_masks") > 0.5
    pts, _ = read_landmarks(split.test / P.TRUTH / "landmarks.json", 6)
    for j in range(6):
        for k in (37, 44, 21, 22):  # eyelids, brows' inner ends
            x, y = np.floor(pts[j, k]).astype(int)
            assert hmd[j, y, x], (j, k)
        for k in (51, 57, 8):  # lips, chin
            x, y = np.floor(pts[j, k]).astype(int)
            assert not hmd[j, y, x], (j, k)
        under = shown[j][hmd[j]]
        assert under.max() < 0.25 and np.ptp(under.mean(0)) < 0.05  # a grey, dark
        assert np.array_equal(shown[j][~hmd[j]], gt[j][~hmd[j]])
        assert 0.05 < hmd[j].mean() < 0.4


def test_the_nearest_frame_of_a_frame_is_itself_unwarped(split):
    """The baseline against its own training frames: each picks itself and the warp through the
    tracked head is the identity (a wrong pose composition or projection would move it)."""
    from geoface.splat.fit import psnr

    out, pick = P.nearest_frame(split.train, split.train)
    assert np.array_equal(pick, np.arange(24))
    frames = Capture(split.train).frames()
    assert min(psnr(out[j], frames[j]) for j in range(0, 24, 5)) > 38


def test_the_baselines_and_the_scorer(split):
    te = Capture(split.test)
    gt = te.images("gt", rgb=True)
    regs = P.regions(split.test)
    assert set(regs) == {"person", "face", "mouth", "occluded"}
    assert (regs["face"] <= regs["person"]).all() and (regs["occluded"] <= regs["person"]).all()
    assert all(regs[k].any(axis=(1, 2)).all() for k in regs)
    # PSNR of known noise: −20 log10 σ
    rng = np.random.default_rng(0)
    s = P.score_regions(np.clip(gt + rng.normal(0, 0.02, gt.shape), 0, 1).astype(np.float32), gt, regs)
    for k in ("face", "mouth", "occluded"):
        assert s[f"psnr_{k}"] == pytest.approx(34.0, abs=0.6) and len(s[f"psnr_{k}_frames"]) == 6
    nf, pick = P.nearest_frame(split.train, split.test)
    mf = P.mean_face(split.train, 6)
    assert nf.shape == mf.shape == gt.shape and (pick < 24).all()
    a, b = P.score_regions(nf, gt, regs), P.score_regions(mf, gt, regs)
    # a second of one person: the nearest frame is close, the mean face blurred
    assert a["psnr_face"] > b["psnr_face"] + 2 and a["psnr_face"] > 24


def test_what_cannot_be_split_is_refused(clip_capture, split, tmp_path):
    r, _ = clip_capture
    with pytest.raises(GeofaceError, match="exists"):
        P.split_capture(r.folder, split.train.parent, quiet=True)
    with pytest.raises(CaptureError, match="test fraction"):
        P.split_capture(r.folder, tmp_path / "x", test=0.0, quiet=True)
    with pytest.raises(CaptureError, match="leaves 1 to test"):
        P.split_index(5, 0.2)
    with pytest.raises(CaptureError, match="missing expressions.npz"):  # no head track: not a `geoface capture` folder
        P.split_capture(split.test, tmp_path / "y", quiet=True)


def test_hmd_remove_takes_a_headset_video(split, tmp_path, capsys):
    """A model registered on the training frames restores the face in an MP4 of the headset frames:
    the video is captured, the headset segmented from its pixels, the person's head (the
    registration's identity, which the model keeps) tracked below it, and the grey box is gone from
    the output (the face drawn there, the sound kept)."""
    pytest.importorskip("torch")
    from geoface.cli import main
    from geoface.video import probe_video, read_video, write_video

    te = Capture(split.test)
    write_video(np.round(te.frames() * 255).astype(np.uint8), tmp_path / "headset.mp4", fps=30,
                audio=split.test / "audio.wav")
    assert main(["hmd", "train", str(split.train), "-o", str(tmp_path / "m"), "--iters", "30", "-q"]) == 0
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["registration_size"] == [160, 160]
    assert np.allclose(cfg["ict_identity"], Capture(split.train).meta()["ict_identity"], atol=1e-6)
    capsys.readouterr()
    assert main(["hmd", "remove", str(tmp_path / "m"), str(tmp_path / "headset.mp4"), "-o", str(tmp_path / "o"),
                 "--video", str(tmp_path / "o.mp4"), "-q"]) == 0
    said = capsys.readouterr().out
    assert "headset.mp4 -> " in said and "head poses: track" in said, said
    n = probe_video(tmp_path / "headset.mp4")["frames"]  # (the encoder may end on the sound's last frame)
    assert n >= 5 and len(list((tmp_path / "o" / "frames").glob("*.png"))) == n and probe_video(tmp_path / "o.mp4")["audio"]
    out, _ = read_video(tmp_path / "o.mp4")
    out = out.astype(np.float32) / 255
    # where the box was (between the eyes, in the first frame's crop), no flat dark grey left
    pts, _ = read_landmarks(split.test / P.TRUTH / "landmarks.json", 6)
    x, y = np.round(pts[0, 27]).astype(int)
    patch = out[0, y - 3:y + 4, x - 3:x + 4]
    assert patch.mean() > 0.3, patch.mean()
    # the same model scored with the baselines on the held-out frames, as `hmd holdout` writes them
    assert main(["hmd", "eval", str(tmp_path / "m"), str(split.test), "--baselines", str(split.train),
                 "--json", str(tmp_path / "e.json"), "-q"]) == 0
    ev = json.loads((tmp_path / "e.json").read_text())["baselines"]
    assert set(ev) == {"avatar", "nearest training frame", "mean training face"}
    assert ev["nearest training frame"]["psnr_occluded"] > ev["mean training face"]["psnr_occluded"]
    assert main(["hmd", "eval", str(tmp_path / "m"), str(split.train), "--baselines", str(split.train), "-q"]) == 2
    capsys.readouterr()
    # a folder that is not a capture, a video that does not exist: one line each
    assert main(["hmd", "remove", str(tmp_path / "m"), str(tmp_path / "none.mp4"), "-o", str(tmp_path / "p"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such video or usage folder" in err


def test_a_headset_video_is_tracked_as_the_registered_person_below_the_headset(split, tmp_path):
    """``capture_clip(identity=..., headset=True)`` on the headset frames: the headset is found in
    every crop (above the mouth, which stays out of it) and kept in ``hmd_masks/``; the head is the
    registration's, held; and the usage folder made from it takes those masks as they are."""
    from geoface.avatar.clip import capture_clip
    from geoface.landmarks import IBUG68_NAMES
    from geoface.video import write_video

    te = Capture(split.test)
    write_video(np.round(te.frames() * 255).astype(np.uint8), tmp_path / "headset.mp4", fps=30)
    ident = Capture(split.train).meta()["ict_identity"]
    r = capture_clip(tmp_path / "headset.mp4", tmp_path / "u", res=160, head_vertices=500, overlay=False,
                     identity=ident, headset=True, quiet=True)
    c = Capture(r.folder)
    meta = c.meta()
    assert meta["headset"] and meta["identity_held"] and np.allclose(meta["ict_identity"], ident, atol=1e-6)
    hmd = c.images("hmd_masks") > 0.5
    lm = c.landmarks()
    mouth = lm.points[:, [lm.names.index(n) for n in IBUG68_NAMES[48:68]]]
    for k in range(len(c)):
        assert hmd[k].mean() > 0.03, (k, hmd[k].mean())  # the box covers the eyes: a good part of the crop
        ys = np.nonzero(hmd[k])[0]
        assert ys.mean() < mouth[k, :, 1].min(), k  # above the mouth
        x, y = np.clip(np.floor(mouth[k]).astype(int), 0, 159).T
        assert not hmd[k][y, x].any(), k  # and none of the mouth's points under it
    usage = P.usage_from_capture(r.folder, tmp_path / "usage", quiet=True)
    assert np.array_equal(Capture(usage).images("hmd_masks") > 0.5, hmd)


def test_the_headset_is_segmented_by_its_own_colour_after_video_encoding(split, clip_capture, tmp_path):
    """The test frames with the drawn headset, through an MP4 (H.264 shifts its bluish grey's
    chroma, so that a fixed saturation test loses part of it) and, recoloured, as white plastic:
    with the face mesh's points, ``headset_masks`` learns the colour where the eyes fall and covers
    more than 90% of the drawn headset in every frame, less than a tenth of its mask beyond 3
    pixels of it; on the clip's own frames, where the eyes are seen, it finds nothing."""
    from scipy.ndimage import binary_dilation

    from geoface.track import facemesh_points, headset_masks, read_frames
    from geoface.video import write_video
    from tests.helpers import white_headset

    te = Capture(split.test)
    truth = te.images("hmd_masks") > 0.5
    rim = np.stack([binary_dilation(t, iterations=3) for t in truth])  # the headset and 3 pixels round it
    drawn = np.round(te.frames() * 255).astype(np.uint8)
    for name, frames in (("grey", drawn), ("white", white_headset(drawn, truth))):
        write_video(frames, tmp_path / f"{name}.mp4", fps=30)
        got = np.stack(read_frames(tmp_path / f"{name}.mp4")[0])
        pts = facemesh_points(list(got), video=True, total=len(got), quiet=True)
        m = headset_masks(got, points=pts)
        covered = (m & truth).sum((1, 2)) / truth.sum((1, 2))
        beyond = (m & ~rim).sum((1, 2)) / m.sum((1, 2))
        assert covered.min() > 0.9 and beyond.max() < 0.1, (name, covered.round(3), beyond.round(3))
    r, _ = clip_capture
    seen = np.round(Capture(r.folder).frames() * 255).astype(np.uint8)
    assert not headset_masks(seen, points=facemesh_points(list(seen), video=True, total=len(seen), quiet=True)).any()


def test_hmd_holdout_writes_the_split(clip_capture, tmp_path, capsys):
    from geoface.cli import main

    r, _ = clip_capture
    assert main(["hmd", "holdout", str(r.folder), "-o", str(tmp_path / "h"), "--test", "0.3", "-q"]) == 0
    out = capsys.readouterr().out
    assert "(21 frames" in out and "(9 frames" in out and "hmd eval --baselines" in out
    assert len(Capture(tmp_path / "h" / "test")) == 9 and (tmp_path / "h" / "test" / "hmd_masks").is_dir()
    assert main(["hmd", "holdout", str(r.folder), "-o", str(tmp_path / "h"), "-q"]) == 2  # exists
    assert "exists" in capsys.readouterr().err

