"""How fast the ICT head track's refinement against the pixels runs (``refine_photometric``), alone
on the machine: one ICT-FaceKit person rendered talking at ``--res`` (``bench_head_track``'s
generator), tracked from the face mesh's points, then refined; per run one JSON line with the
landmark fit's and the refinement's seconds and frames per second, and the photometric error
before and after (the same figures on every run: only the time may differ). The first line is
the machine's calibration (``bench_scale.calibration``: the same machine is slower some hours).

    python bench/bench_head_refine.py [--seed 13] [--res 512] [--seconds 3] [--repeat 2] [--cache DIR] [--out FILE]

``--cache``: the rendered clip and its points are kept there (an npz) and read back on the next
run, so that two versions of the code can be timed on the same frames (copy this file into an
older checkout's ``bench/`` and run it there: it imports the geoface beside it).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    from _results import emitter
    from bench_head_track import render_person
    from bench_scale import calibration

    from geoface.track import facemesh_points
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import fit_head_track

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=None, help="keep the rendered clip here (npz)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    emit = emitter(a.out)
    code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=Path(__file__).parent).stdout.strip()
    emit({**calibration(), "code": code})
    clip = None if a.cache is None else a.cache / f"ict{a.seed}_{a.res}_{a.seconds:g}s.npz"
    if clip is not None and clip.exists():
        z = np.load(clip)
        frames, pts = list(z["frames"]), z["points"]
    else:
        _, frames, _, _, _ = render_person(a.seed, a.res, a.seconds)
        pts = facemesh_points(frames, video=True, quiet=True)
        if clip is not None:
            clip.parent.mkdir(parents=True, exist_ok=True)
            np.savez(clip, frames=np.stack(frames), points=pts)
    rgb = np.stack(frames).astype(np.float32) / 255.0
    masks = (rgb.max(-1) > 0).astype(np.float32)
    for run in range(a.repeat):
        t0 = time.perf_counter()
        tr = fit_head_track(pts, (a.res, a.res), quiet=True)
        t1 = time.perf_counter()
        _, ref = refine_photometric(tr, rgb, masks, pts, quiet=True)
        t2 = time.perf_counter()
        emit({"case": "refine", "code": code, "seed": a.seed, "res": a.res, "frames": len(frames), "run": run,
              "fit_seconds": round(t1 - t0, 2), "fit_fps": round(len(frames) / (t1 - t0), 2),
              "refine_seconds": round(t2 - t1, 1), "refine_fps": round(len(frames) / (t2 - t1), 3),
              "photo_err_before": round(float(np.nanmean(ref.before)), 5),
              "photo_err_after": round(float(np.nanmean(ref.after)), 5)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
