"""The capture folder's one reader and writer, and a real clip made into a capture."""
from __future__ import annotations

import json

import numpy as np
import pytest

from geoface.camera import Camera
from geoface.capture import (Capture, write_camera, write_dense, write_expressions, write_frame, write_head_poses,
                             write_landmarks, write_meta)
from geoface.errors import CaptureError


def _folder(tmp_path, T=3, size=16):
    d = tmp_path / "cap"
    for k in range(T):
        write_frame(d, k, np.full((size, size, 3), 0.1 * (k + 1), np.float32))
    write_camera(d, Camera(20.0, 20.0, size / 2, size / 2, size, size, np.eye(3), np.zeros(3)))
    return d


def test_what_is_written_is_read_back(tmp_path):
    T = 4
    d = _folder(tmp_path, T)
    pts = np.random.default_rng(0).uniform(0, 16, (T, 68, 2))
    write_landmarks(d, pts, found=[True, False, True, True], confidence=[0.9, 0.0, 0.8, 0.7], tracker="x")
    dense = np.random.default_rng(1).uniform(0, 16, (T, 468, 2))
    write_dense(d, dense, np.ones(T, bool), np.ones(T))
    R = np.stack([np.eye(3)] * T)
    write_head_poses(d, R, np.zeros((T, 3)), np.array([0, -0.1, 0.0]))
    write_expressions(d, np.full((T, 2), 0.5), ["jawOpen", "eyeBlink_L"])
    write_meta(d, {"fps": 30})
    cap = Capture(d)
    assert len(cap) == T and cap.frames().shape == (T, 16, 16, 3)
    lm = cap.landmarks()
    assert np.allclose(lm.points, pts, atol=1e-3) and lm.found.tolist() == [True, False, True, True]
    assert lm.tracker == "x" and lm.names[0] == "jaw_00" and np.allclose(lm.confidence, [0.9, 0, 0.8, 0.7])
    assert np.allclose(cap.dense()[0], dense, atol=1e-3)
    assert cap.head_poses()[2].tolist() == [0, -0.1, 0]
    W, names = cap.expressions()
    assert names == ["jawOpen", "eyeBlink_L"] and np.allclose(W, 0.5)
    assert cap.meta()["fps"] == 30 and cap.audio() is None and cap.head_mesh() is None
    # a slice of the frames takes its landmarks and poses along
    part = Capture(d, frames=slice(1, 3))
    assert len(part) == 2 and np.allclose(part.landmarks().points, pts[1:3], atol=1e-3)
    assert len(part.head_poses()[0]) == 2
    # a renderer's landmarks (no found/confidence) read as all found, confidence 1
    (d / "landmarks.json").write_text(json.dumps({"points": pts.tolist()}))
    lm = Capture(d).landmarks()
    assert lm.found.all() and (lm.confidence == 1).all() and lm.tracker is None


@pytest.mark.parametrize("damage, match", [
    (lambda d: (d / "landmarks.json").write_text("{"), "malformed landmarks"),
    (lambda d: (d / "landmarks.json").write_text(json.dumps({"points": [[[0, 0]] * 68] * 2})), "frames=3"),
    (lambda d: (d / "camera.json").write_text(json.dumps({"fx": 1})), "needs fx"),
    (lambda d: write_camera(d, Camera(20.0, 20.0, 8, 8, 32, 32, np.eye(3), np.zeros(3))), "camera.json says 32"),
    (lambda d: np.savez(d / "head_poses.npz", R=np.zeros((2, 3, 3)), t=np.zeros((2, 3)), pivot=np.zeros(3)), "fit 3"),
    (lambda d: np.savez(d / "expressions.npz", weights=np.zeros((3, 2)), names=np.array(["a"])), "do not fit"),
    (lambda d: np.savez(d / "landmarks_dense.npz", points=np.zeros((3, 68, 2)), found=np.ones(3, bool),
                        confidence=np.ones(3)), "468"),
    (lambda d: (d / "meta.json").write_text("[1]"), "JSON object"),
])
def test_a_damaged_capture_is_a_one_line_capture_error(tmp_path, damage, match):
    d = _folder(tmp_path)
    write_landmarks(d, np.zeros((3, 68, 2)))
    damage(d)
    cap = Capture(d)
    with pytest.raises(CaptureError, match=match) as e:
        cap.landmarks(), cap.camera(), cap.head_poses(), cap.expressions(), cap.dense(), cap.meta()
    assert "\n" not in str(e.value)


def test_no_frames_is_an_error(tmp_path):
    (tmp_path / "frames").mkdir()
    with pytest.raises(CaptureError, match="no frames"):
        Capture(tmp_path)
    with pytest.raises(CaptureError, match="not a folder"):
        Capture(tmp_path / "nothing")


def test_face_crops_follow_the_face_smoothly_and_keep_it_whole():
    from geoface.avatar.clip import FACE_OVAL, face_crops

    rng = np.random.default_rng(0)
    T = 60
    base = np.zeros((468, 2))
    base[list(FACE_OVAL)] = rng.uniform(-50, 50, (len(FACE_OVAL), 2))
    path = np.c_[300 + 80 * np.sin(np.linspace(0, 3, T)), 250 + np.linspace(0, 40, T)]
    jitter = rng.normal(0, 3, (T, 1, 2))
    pts = base[None] + path[:, None] + jitter
    found = np.ones(T, bool)
    found[20:23] = False
    pts[20:23] = np.nan
    boxes = face_crops(pts, found, fps=30)
    assert np.ptp(boxes[:, 2]) == 0  # one side for the clip
    assert np.abs(np.diff(boxes[:, :2], 2, axis=0)).max() < 1.0  # no jitter left (3 px in)
    for k in np.flatnonzero(found):  # the face whole inside every crop
        cx, cy, s = boxes[k]
        q = pts[k, list(FACE_OVAL)]
        assert (np.abs(q[:, 0] - cx) < s / 2).all() and (np.abs(q[:, 1] - cy) < s / 2).all()


def test_a_real_clip_becomes_a_capture_both_avatars_read(clip_capture):
    from geoface.hfm.data import load_video
    from geoface.thgs.data import load_talking

    r, _ = clip_capture
    cap = Capture(r.folder)
    assert r.found == r.frames == len(cap) == 30 and r.audio and cap.audio() is not None
    masks = cap.masks()
    frames = cap.frames()
    # the person kept, the background (a blue wall) gone: blue-dominant pixels only off the mask
    blue = (frames[..., 2] > frames[..., 0] + 0.15)
    assert blue.mean() < 0.01 and 0.2 < (masks > 0.5).mean() < 0.9
    soft = ((masks > 0.05) & (masks < 0.95)).mean()
    assert soft > 0.001  # a soft edge
    lm = cap.landmarks()
    assert lm.tracker and lm.found.all() and (lm.confidence > 0.5).all()
    # the face's landmarks inside the crop and the face centred in it
    assert (lm.points > 0).all() and (lm.points < 160).all()
    assert abs(lm.points[:, 30, 0].mean() - 80) < 20
    R, t, piv = cap.head_poses()
    assert np.allclose(R[0], np.eye(3), atol=1e-9) and np.allclose(t[0], 0, atol=1e-9)
    W, names = cap.expressions()
    assert W.shape == (30, 53) and "jawOpen" in names and (W >= 0).all() and (W <= 1).all()
    # the talking mouth opens and closes within one second of speech
    assert np.ptp(W[:, names.index("jawOpen")]) > 0.05
    video = load_video(r.folder, need_mesh=True)
    assert video.y_split is not None and video.poses is not None
    talk = load_talking(r.folder)
    assert talk.template.n_expr == 52 and talk.rot.shape[0] == 30 and np.isfinite(talk.audio).all()


def test_the_overlay_shows_the_tracked_head_on_the_face(clip_capture):
    """Pixels: the right half is the frame with the head drawn over it in blue; it differs from
    the left half where the face is (between the eyes, the nose, the mouth) and not far outside it."""
    from geoface.video import probe_video, read_video

    r, _ = clip_capture
    info = probe_video(r.folder / "overlay.mp4")
    assert info["frames"] == 30 and info["audio"]
    frames, _ = read_video(r.folder / "overlay.mp4")
    lm = Capture(r.folder).landmarks().points
    f = frames[10].astype(np.float32) / 255
    left, right = f[:, :160], f[:, 160:320]
    tint = (right[..., 2] - right[..., 0]) - (left[..., 2] - left[..., 0])  # bluer on the right
    for name in (30, 51, 8, 27):  # nose tip, upper lip, chin, nose bridge
        x, y = np.round(lm[10, name]).astype(int)
        assert tint[y - 2:y + 3, x - 2:x + 3].mean() > 0.08, name
    assert abs(tint[:8, :8]).mean() < 0.02  # the corner, off the head: untouched


def test_capture_cli_writes_a_folder_and_refuses_what_it_cannot_use(clip_capture, tmp_path, capsys):
    from geoface.cli import main

    _, clip = clip_capture
    assert main(["capture", str(clip), "-o", str(tmp_path / "c"), "--res", "96", "--no-overlay", "-q"]) == 0
    out = capsys.readouterr().out
    assert "30 frames" in out and "ICT head tracked" in out and (tmp_path / "c" / "head.ply").is_file()
    # the folder exists: not replaced without --force
    assert main(["capture", str(clip), "-o", str(tmp_path / "c"), "-q"]) == 2
    assert "exists" in capsys.readouterr().err
    # a clip without a face
    from geoface.video import write_video

    write_video(np.zeros((5, 64, 64, 3), np.uint8), tmp_path / "dark.mp4", fps=5)
    assert main(["capture", str(tmp_path / "dark.mp4"), "-o", str(tmp_path / "d"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "no face" in err and err.count("\n") == 1 and not (tmp_path / "d").exists()
    assert main(["capture", str(tmp_path / "missing.mp4"), "-o", str(tmp_path / "e"), "-q"]) == 2
    assert main(["capture", str(clip), "-o", str(tmp_path / "f"), "--audio", str(clip), "-q"]) == 2
    assert "WAV" in capsys.readouterr().err


def test_refining_against_the_pixels_matches_the_face_better(clip_capture):
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import fit_head_track

    r, _ = clip_capture
    cap = Capture(r.folder, frames=slice(0, 5))  # five frames: enough to see it match better
    pts, found, _ = cap.dense()
    tr = fit_head_track(pts, (160, 160), found=found, focal_init=cap.meta()["focal_px"], quiet=True)
    out, ref = refine_photometric(tr, cap.frames(), cap.masks(), pts, passes=1, quiet=True)
    assert np.nanmean(ref.after) < 0.95 * np.nanmean(ref.before), (ref.before, ref.after)
    # it moves the head by little: the landmarks keep it in place
    ang = np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", out.R, tr.R) - 1) / 2, -1, 1)))
    assert ang.max() < 5.0


def test_capture_refuses_what_is_not_a_clip_before_tracking(tmp_path):
    from geoface.avatar.clip import capture_clip
    from geoface.errors import GeofaceError
    from geoface.images import save_image

    (tmp_path / "one").mkdir()
    save_image(tmp_path / "one" / "a.png", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(GeofaceError, match="2 frames or more"):
        capture_clip(tmp_path / "one", tmp_path / "o1", quiet=True)
    (tmp_path / "fake.mp4").write_text("not a video")
    with pytest.raises(GeofaceError, match="not a video ffmpeg can read") as e:
        capture_clip(tmp_path / "fake.mp4", tmp_path / "o2", quiet=True)
    assert "\n" not in str(e.value)
    save_image(tmp_path / "photo.png", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(GeofaceError, match="one image"):
        capture_clip(tmp_path / "photo.png", tmp_path / "o3", quiet=True)
    with pytest.raises(GeofaceError, match="res"):
        capture_clip(tmp_path / "one", tmp_path / "o4", res=8, quiet=True)
    assert not any((tmp_path / f"o{k}").exists() for k in range(1, 5))


def test_a_frames_folder_streams_and_refuses_a_frame_of_another_size(tmp_path):
    from geoface.images import save_image
    from geoface.track import FrameSource

    for k in range(3):
        save_image(tmp_path / f"{k:03d}.png", np.full((6, 8, 3), 40 * k, np.uint8))
    src = FrameSource(tmp_path)
    assert len(src) == 3 and src.size == (8, 6) and [int(f[0, 0, 0]) for f in src] == [0, 40, 80]
    save_image(tmp_path / "003.png", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(Exception, match="same size|not 8×6"):
        list(FrameSource(tmp_path))
