"""The z-buffer's compiled loop against its NumPy loop (``rasterize_mesh(native=...)``) on the
renders the face search makes: an ICT-FaceKit head (22K triangles) seen from the search's 26
directions at 64², 128² and 256², and close up at 512²; per resolution one JSON line with the
mean milliseconds a render of each (the whole call: the camera's projection and the checks
included), the speed-up, and whether the two wrote the same arrays to the last bit. The first
line is the machine's calibration (``bench_scale.calibration``).

    python bench/bench_zbuffer.py [--repeat 3] [--out bench/results/convert/zbuffer.jsonl]
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
    from bench_scale import calibration

    from geoface.mesh.raster import _native_zbuffer, rasterize_mesh
    from geoface.synth.ict import ict_head, load_ict_model
    from geoface.track.look import any_up, camera_at, principal_frame, search_views

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="each render timed this many times (the best kept)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    if _native_zbuffer() is None:
        print("the compiled z-buffer is not built (pip install -e . builds it)", file=sys.stderr)
        return 2
    emit = emitter(a.out)
    code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=Path(__file__).parent).stdout.strip()
    emit({**calibration(), "code": code})
    head = ict_head(load_ict_model(), seed=1)
    V, F = head.V.astype(np.float64), head.F.astype(np.int64)
    c, r, E = principal_frame(V, F)
    for res, zoom in ((64, 1.0), (128, 1.0), (256, 1.0), (512, 0.5)):
        cams = [camera_at(c, E @ g, E @ any_up(g), r * zoom, res) for g in search_views()]
        ms, same = {}, True
        for native in (False, True):
            best = []
            for cam in cams:
                ts = []
                for _ in range(a.repeat):
                    t0 = time.perf_counter()
                    out = rasterize_mesh(V, F, cam, native=native)
                    ts.append(time.perf_counter() - t0)
                best.append(min(ts))
                if native:
                    same &= all(np.array_equal(x, y) for x, y in zip(out, rasterize_mesh(V, F, cam, native=False)))
            ms[native] = 1000 * float(np.mean(best))
        emit({"case": "zbuffer", "code": code, "mesh": "ict head (seed 1)", "triangles": len(F), "res": res,
              "views": len(cams), "numpy_ms": round(ms[False], 2), "native_ms": round(ms[True], 2),
              "speedup": round(ms[False] / ms[True], 2), "identical": bool(same)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
