"""The headset found in a real headset video's frames: ``geoface.track.headset_masks`` with the
face mesh's points (the headset's colour learned where the eyes fall) against the fixed grey test
it replaces (no points), scored against the drawn headset's own masks.

The work folders of ``bench/bench_headset_track.py`` are used (made when missing, as there): a
real clip's first ``--seconds`` captured at ``--res``, split in half by time, the second half
given the box headset at the tracked pose and written as an MP4 (H.264, as a user's video is).
Its decoded frames are segmented each way, and again with the headset recoloured white (its
shading kept) and written as an MP4 too. Per clip, colour and way: the IoU with the drawn
headset's masks (mean, 10th percentile, least over the frames), the share of the drawn headset
covered (what a composite must replace) and the share of the mask beyond 3 pixels of it (face
replaced for nothing), mean and worst frame; and on the clip's first half (no headset, the eyes
seen) the share of frames given a headset. One JSON line per row.

    python bench/bench_headset_masks.py man_closeup.mp4 woman_blue_backdrop.mp4 --work /tmp/hs \\
        --out bench/results/hfm_eval/real_headset_masks.jsonl
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_headset_track import clip_arguments, clip_work  # noqa: E402  (the same clips and work folders)
from tests.helpers import white_headset  # noqa: E402

#: the two ways compared: whether the face mesh's points are given
WAYS = {"fixed grey test (no points)": False, "colour learned at the eyes (points)": True}


def _through_mp4(frames: np.ndarray, path: Path) -> np.ndarray:
    from geoface.track import read_frames
    from geoface.video import write_video

    write_video(frames, path, fps=25)
    return np.stack(read_frames(path)[0])


def main(argv=None) -> int:
    from scipy.ndimage import binary_dilation

    from geoface.capture import Capture
    from geoface.track import facemesh_points, headset_masks

    a = clip_arguments(argparse.ArgumentParser(description=__doc__.splitlines()[0])).parse_args(argv)
    rows = []
    for name in a.clips:
        work = clip_work(name, a)
        te, tr = Capture(work / "split" / "test"), Capture(work / "split" / "train")
        truth = te.images("hmd_masks") > 0.5
        rim = np.stack([binary_dilation(t, iterations=3) for t in truth])  # the headset and 3 pixels round it
        drawn = np.round(te.frames() * 255).astype(np.uint8)
        seen = np.round(tr.frames() * 255).astype(np.uint8)
        seen_pts = facemesh_points(list(seen), video=True, total=len(seen), quiet=True)
        found_without = {way: float(headset_masks(seen, **({"points": seen_pts} if learned else {})).any((1, 2)).mean())
                         for way, learned in WAYS.items()}  # the same frames for both colours
        for colour, frames in (("grey (drawn)", drawn), ("white", white_headset(drawn, truth))):
            got = _through_mp4(frames, work / f"masks_{colour.split()[0]}.mp4")
            pts = facemesh_points(list(got), video=True, total=len(got), quiet=True)
            for way, learned in WAYS.items():
                m = headset_masks(got, **({"points": pts} if learned else {}))
                iou = (m & truth).sum((1, 2)) / np.maximum((m | truth).sum((1, 2)), 1)
                cover = (m & truth).sum((1, 2)) / np.maximum(truth.sum((1, 2)), 1)
                spill = (m & ~rim).sum((1, 2)) / np.maximum(m.sum((1, 2)), 1)
                rows.append({"bench": "headset_masks", "clip": name, "seconds": a.seconds, "res": a.res,
                             "headset": colour, "way": way, "frames": int(len(got)),
                             "iou_mean": round(float(iou.mean()), 3), "iou_p10": round(float(np.percentile(iou, 10)), 3),
                             "iou_min": round(float(iou.min()), 3),
                             "covered_mean": round(float(cover.mean()), 4), "covered_min": round(float(cover.min()), 4),
                             "spilled_mean": round(float(spill.mean()), 4), "spilled_max": round(float(spill.max()), 4),
                             "frames_without_headset": int(len(seen)),
                             "headset_found_without_one": round(found_without[way], 3)})
                print(json.dumps(rows[-1]), flush=True)
    if a.out:
        with open(a.out, "a") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
