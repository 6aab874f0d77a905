"""The head under a headset, tracked on a real clip: how near the poses that ``hmd remove MODEL
VIDEO`` tracks on a headset video come to those the same frames gave without the headset.

A real clip (``../shared/data/videos/``; its first ``--seconds``) is captured at ``--res``
(``geoface capture`` with the photometric refinement: the whole face seen), then split by time as
``hmd holdout`` splits it, here half and half (``--test``): the second half gets the box headset
drawn at the tracked pose, and is written out as an MP4, the headset video. That video is captured
again four ways, and each way's head rotations in the camera are compared with the whole-face
track's of the same frames, about the clip's one constant rotation between them (the crops and
the head's frame differ): the error's mean angle (degrees) and its RMS about each camera axis
(x: pitch, y: yaw, z: roll).

* ``fresh identity, all points`` — what ``hmd remove VIDEO`` did before: a new head fitted to all
  468 face-mesh points, those MediaPipe guesses under the visor included;
* ``identity held, all points`` — the registration's head (the training half's ``ict_identity``);
* ``identity held, below the headset`` — and only the points below it
  (:func:`geoface.track.head_track.below_headset`);
* ``identity held, below the headset, refined`` — and refined against the pixels below the
  segmented headset (what ``hmd remove VIDEO`` does now, before ``--pose-align``).

The reference is itself a track (no truth exists for a real clip): its own error adds to each
row. One JSON line per clip and way. ``--work DIR`` keeps the captures and reuses them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

WAYS = {
    "fresh identity, all points": dict(),
    "identity held, all points": dict(held=True),
    "identity held, below the headset": dict(held=True, headset=True),
    "identity held, below the headset, refined": dict(held=True, headset=True, refine=True),
}


def _camera_rotations(cap) -> np.ndarray:
    """The head's rotation in the camera per frame: camera.json's turn after head_poses.npz's."""
    R, _, _ = cap.head_poses()
    return np.einsum("ij,tjk->tik", cap.camera().R, R)


def _errors(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """``Ra`` against ``Rb`` (T, 3, 3) after the one rotation between the heads' frames that best
    lays them on each other: per frame the rotation vector (degrees) of what is left."""
    from scipy.spatial.transform import Rotation

    off = Rotation.from_matrix(np.einsum("tji,tjk->tik", Rb, Ra)).mean().as_matrix()
    return Rotation.from_matrix(np.einsum("tij,tkj->tik", Ra @ off.T, Rb)).as_rotvec(degrees=True)


def clip_arguments(ap):
    """The clips, their length and size, the split and the work folder (shared with
    ``bench_headset_masks.py``)."""
    ap.add_argument("clips", nargs="+", help="clip names in ../shared/data/videos/")
    ap.add_argument("--seconds", type=float, default=6.0, help="the clip's first seconds (6)")
    ap.add_argument("--res", type=int, default=192, help="the crops' side (192)")
    ap.add_argument("--test", type=float, default=0.5, help="the held-out share that gets the headset (0.5)")
    ap.add_argument("--work", required=True, help="folder for the captures (reused when there)")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file too")
    return ap


def clip_work(name: str, a) -> Path:
    """The clip's work folder: its first ``a.seconds`` captured at ``a.res`` with the refinement
    and split by time (made when missing)."""
    from geoface.avatar import protocol as P
    from geoface.avatar.clip import capture_clip
    from tests.helpers import short_clip

    work = Path(a.work) / f"{Path(name).stem}_{a.res}"
    work.mkdir(parents=True, exist_ok=True)
    if not (work / "split").is_dir():
        clip = short_clip(name, work, seconds=a.seconds)
        capture_clip(clip, work / "cap", res=a.res, head_vertices=3000, overlay=False, refine=True, quiet=True)
        P.split_capture(work / "cap", work / "split", test=a.test, quiet=True)
    return work


def main(argv=None) -> int:
    from geoface.avatar.clip import capture_clip
    from geoface.capture import Capture
    from geoface.video import write_video

    a = clip_arguments(argparse.ArgumentParser(description=__doc__.splitlines()[0])).parse_args(argv)
    for name in a.clips:
        work = clip_work(name, a)
        te = Capture(work / "split" / "test")
        ident = Capture(work / "split" / "train").meta()["ict_identity"]
        video = work / "headset.mp4"
        if not video.is_file():
            write_video(np.round(te.frames() * 255).astype(np.uint8), video, fps=25)
        Rt = _camera_rotations(te)
        from scipy.spatial.transform import Rotation

        motion = Rotation.from_matrix(np.einsum("tij,kj->tik", Rt, Rotation.from_matrix(Rt).mean().as_matrix()))
        for way, kw in WAYS.items():
            out = work / ("u_" + "_".join(way.replace(",", "").split()))
            t0 = time.time()
            if not out.is_dir():
                capture_clip(video, out, res=a.res, overlay=False, head_vertices=1500, quiet=True,
                             identity=ident if kw.get("held") else None, headset=kw.get("headset", False),
                             refine=kw.get("refine", False))
            c = Capture(out)
            n = min(len(c), len(Rt))
            e = _errors(_camera_rotations(c)[:n], Rt[:n])
            secs = c.meta().get("seconds", {})
            row = {"bench": "headset_track", "clip": name, "seconds": a.seconds, "res": a.res, "frames": n,
                   "way": way, "rot_error_mean_deg": round(float(np.linalg.norm(e, axis=1).mean()), 3),
                   "rot_error_rms_xyz_deg": np.round(np.sqrt((e ** 2).mean(0)), 3).tolist(),
                   "reference_motion_mean_deg": round(float(np.degrees(motion.magnitude()).mean()), 3),
                   "track_seconds": round(float(secs.get("head_track", 0.0)), 1),
                   "refine_seconds": round(float(secs.get("refine", 0.0)), 1),
                   "wall_s_this_run": round(time.time() - t0, 1)}
            if kw.get("headset"):  # the headset's masks (they bound the refinement's pixels)
                row["segmenter"] = "colour learned at the eyes (face-mesh points)"
            line = json.dumps(row)
            print(line, flush=True)
            if a.out:
                with open(a.out, "a") as f:
                    f.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
