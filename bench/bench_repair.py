"""Time make_disk on procedural heads of growing size and on the shared real meshes.

Prints one JSON line per case: name, input size, seconds (best of --repeat), output
size, area change and the steps that ran.

    python bench/bench_repair.py [--sizes 10000 50000 200000] [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "data_tools"))


def case(name, V, F, repeat, **kw):
    from geoface.repair import make_disk

    best = np.inf
    res = None
    for _ in range(repeat):
        t = time.perf_counter()
        res = make_disk(V, F, **kw)
        best = min(best, time.perf_counter() - t)
    steps = sorted({c["step"] for c in res.changes})
    print(
        json.dumps(
            {
                "name": name,
                "vertices_in": int(len(V)),
                "faces_in": int(len(F)),
                "seconds": round(best, 4),
                "vertices_out": int(len(res.V)),
                "is_disk": bool(res.report.is_disk),
                "area_change": round((res.area_after - res.area_before) / res.area_before, 5),
                "steps": steps,
            }
        ),
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 50000, 200000])
    ap.add_argument("--repeat", type=int, default=1)
    default_meshes = REPO.parent / "shared" / "data" / "meshes"
    ap.add_argument("--meshes", default=str(default_meshes if default_meshes.is_dir() else REPO / "tests" / "data" / "meshes"))
    args = ap.parse_args()
    from make_messy_head import messy_head

    from geoface.mesh.io import load_mesh
    from geoface.synth import procedural_head

    for n in args.sizes:
        t = time.perf_counter()
        head = procedural_head(n_vertices=n, seed=0)
        gen = time.perf_counter() - t
        print(json.dumps({"name": f"procedural_head_generate_{n // 1000}k", "vertices": int(len(head.V)), "seconds": round(gen, 4)}), flush=True)
        case(f"head_clean_{n // 1000}k", head.V, head.F, args.repeat)
        V, F = messy_head(n, seed=0)
        case(f"head_messy_{n // 1000}k", V, F, args.repeat)
    for p in sorted(Path(args.meshes).glob("*.obj")):
        m = load_mesh(p)
        case(p.stem, m.V, m.F, args.repeat)


if __name__ == "__main__":
    main()
