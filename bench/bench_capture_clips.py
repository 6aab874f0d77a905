"""``geoface capture`` on the real clips of ``../shared/data/videos`` (never copied into the
repository): seconds per stage and frames per second of the head track at 512², and how well the
track explains what it did not see — the reprojection error (pixels of the 512² crop, and in
face widths) of held-out face-mesh points (every fifth of MediaPipe's 468, left out of the fit)
— beside a trivial baseline: the mean ICT head posed by PnP on the same points (no identity, no
expression). With ``--refine``, the photometric refinement on the clip's first ``--refine-frames``
frames: the photometric error (mean absolute RGB difference over the visible face, after each
frame's gain and offset) before and after, and its frames per second. ``--speed``: only the
capture's seconds per stage, without the overlay (run on a quiet machine for the timings).

One JSON line per clip and measurement.

    python bench/bench_capture_clips.py [--videos DIR] [--res 512] [--refine] [--out FILE]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
CLIPS = ("woman_blue_backdrop.mp4", "man_closeup.mp4", "selfie_glasses.mp4")


def main(argv=None) -> int:
    from geoface.avatar.clip import capture_clip
    from geoface.capture import Capture
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import point_bases, pnp, fit_head_track

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", default=str(ROOT.parent / "shared" / "data" / "videos"))
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--refine", action="store_true")
    ap.add_argument("--refine-frames", type=int, default=90)
    ap.add_argument("--speed", action="store_true",
                    help="only the seconds per stage (no overlay, no held-out fit): for timing on a quiet machine")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="geoface_clips_"))

    from _results import emitter

    emit = emitter(a.out)

    for name in CLIPS:
        src = Path(a.videos) / name
        t0 = time.perf_counter()
        r = capture_clip(src, work / Path(name).stem, res=a.res, overlay=not a.speed, quiet=True)
        wall = time.perf_counter() - t0
        emit({"clip": name, "what": "speed" if a.speed else "capture", "res": a.res, "frames": r.frames, "found": r.found, "fps_video": r.fps,
              "wall_s": round(wall, 1), "seconds": {k: round(v, 1) for k, v in r.seconds.items()},
              "head_track_fps": round(r.frames / r.seconds["head_track"], 1), "residual_px": round(r.residual_px, 3),
              "focal_px": round(r.focal, 1), "crop_side_px": round(r.side, 1)})
        if a.speed:
            continue
        cap = Capture(r.folder)
        pts, found, _ = cap.dense()
        use = np.ones(468, bool)
        use[::5] = False
        tr = fit_head_track(pts, (a.res, a.res), found=found, focal_init=cap.meta()["focal_px"], use=use, quiet=True)
        width = np.linalg.norm(pts[:, 234] - pts[:, 454], axis=-1)
        e = np.linalg.norm(tr.points() - pts, axis=-1)[found][:, ~use]
        mean = point_bases()[0]
        eb = []
        for k in np.flatnonzero(found):
            pose = pnp(mean[use], pts[k, use], tr.focal, tr.centre)
            X = mean @ pose[0].T + pose[1]
            uv = np.stack([tr.focal * X[:, 0] / X[:, 2] + tr.centre[0], tr.focal * X[:, 1] / X[:, 2] + tr.centre[1]], 1)
            eb.append(np.linalg.norm(uv - pts[k], axis=-1)[~use])
        eb = np.stack(eb)
        wf = width[found][:, None]
        emit({"clip": name, "what": "held_out_points", "res": a.res, "held_out": int((~use).sum()),
              "track_mean_px": round(float(e.mean()), 3), "track_p95_px": round(float(np.percentile(e, 95)), 3),
              "track_mean_face_widths": round(float((e / wf).mean()), 5),
              "baseline": "mean ICT head, PnP", "baseline_mean_px": round(float(eb.mean()), 3),
              "baseline_p95_px": round(float(np.percentile(eb, 95)), 3),
              "baseline_mean_face_widths": round(float((eb / wf).mean()), 5)})
        if a.refine:
            n = min(a.refine_frames, len(cap))
            sub = Capture(r.folder, frames=slice(0, n))
            frames, masks = sub.frames(), sub.masks()
            p = pts[:n]
            tr = fit_head_track(p, (a.res, a.res), found=found[:n], focal_init=cap.meta()["focal_px"], quiet=True)
            t0 = time.perf_counter()
            _, ref = refine_photometric(tr, frames, masks, p, quiet=True)
            sec = time.perf_counter() - t0
            emit({"clip": name, "what": "photometric_refinement", "res": a.res, "frames": n,
                  "photo_err_before": round(float(np.nanmean(ref.before)), 4),
                  "photo_err_after": round(float(np.nanmean(ref.after)), 4),
                  "frames_improved": int(np.sum(ref.after < ref.before)), "fps": round(n / sec, 2)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
