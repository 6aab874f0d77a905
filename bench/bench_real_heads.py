"""How long a labelled set of ICT-FaceKit heads takes to build, and how clean its heads are as
meshes: the yardstick the DDPM's samples are judged against (``geoface.ddpm.evaluate.mesh_validity``).

Builds ``geoface dataset ict -o DIR --count N --res R --augment 1 --workers W`` in a fresh process
(wall seconds, heads per minute, failures), then reconstructs every item and reports the share of
faces folded against the normal channel and the share self-intersecting (pymeshlab's exact test):
mean and worst over the heads, and how many are valid disks.

    python bench/bench_real_heads.py [--count 100] [--res 64] [--workers 2] [--out FILE]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from _results import emitter  # noqa: E402


def emit(row: dict, out: Path | None) -> None:
    emitter(out)({k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=100, help="heads (100)")
    ap.add_argument("--res", type=int, default=64, help="geometry-image side (64, as the DDPM results)")
    ap.add_argument("--workers", type=int, default=2, help="build processes (2)")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    a = ap.parse_args()
    import numpy as np

    from geoface.gimage import load_gimage
    from geoface.ddpm.evaluate import mesh_validity

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "ict"
        cmd = [sys.executable, "-m", "geoface", "dataset", "ict", "-o", str(out), "--count", str(a.count), "--res",
               str(a.res), "--augment", "1", "--workers", str(a.workers), "--quiet"]
        t = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, GEOFACE_QUIET="1"))
        secs = time.perf_counter() - t
        items = sorted(m.parent for m in out.rglob("meta.json") if (m.parent / "position.png").exists())
        emit({"case": "build", "count": a.count, "res": a.res, "workers": a.workers, "rc": p.returncode,
              "seconds": secs, "items": len(items), "failed": a.count - len(items),
              "heads_per_minute": 60 * len(items) / secs, "cpus": os.cpu_count()}, a.out)
        folded, crossing, valid = [], [], 0
        for item in items:
            v = mesh_validity(load_gimage(item))
            valid += bool(v.valid)
            if v.faces > 0 and v.folded_faces >= 0:
                folded.append(v.folded_faces / v.faces)
            if v.faces > 0 and v.self_intersecting_faces >= 0:
                crossing.append(v.self_intersecting_faces / v.faces)
    f, c = np.array(folded), np.array(crossing)
    emit({"case": "validity", "res": a.res, "heads": len(items), "valid": valid,
          "folded_share_mean": float(f.mean()), "folded_share_max": float(f.max()),
          "self_intersecting_share_mean": float(c.mean()), "self_intersecting_share_max": float(c.max())}, a.out)


if __name__ == "__main__":
    main()
