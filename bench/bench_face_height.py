"""Where the face lands down a whole head's geometry image, and what moves it: the corners or the
face magnification λ.  One JSON line per head and setting.

A head opened at the neck: the neck loop becomes the image border, the point under the chin the
middle of the bottom side.  Per setting: the nose's, eyes' and chin's rows (fractions of the
height from the top) after the conformal map and after optimal transport, and the share of the
measure (area, ×λ on the face) below the nose in the conformal map, which is what places the
nose after OT (a measure-preserving map puts a point where the mass below it says).  Settings:
the bottom side's share of the neck loop (``bottom``: 1/4 is the default, equal quarters; the
top side shrinks as the bottom grows, the sides stay 1/4) at λ = 2.5, and λ at the default
corners.

    python bench/bench_face_height.py [--ict 3] [--meshes face.obj ninjaHead_Low.obj decimated-max.obj]
        [--out bench/results/stress/face_height.jsonl]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "data_tools"))
sys.path.insert(0, str(REPO / "bench"))


def measure_head(case, bottoms=(0.25, 0.3125, 0.375, 0.4375), lams=(1.0, 2.5, 5.0, 10.0)):
    from geoface.mesh.core import vertex_areas
    from geoface.param.corners import _loop, _reference, _split
    from geoface.param.measure import measure_preserving_map
    from geoface.param.ricci import RicciFlowSolver
    from geoface.repair import make_disk
    from geoface.repair.upright import template_face_region

    d = make_disk(case.V, case.F, up="auto", quiet=True)
    V, F = d.V, d.F
    roi = template_face_region(V, d.frame) if d.frame is not None and d.frame.template is not None else None
    if roi is None:
        from geoface.pipeline import face_region

        roi = face_region(V, d.frame.front)
    loop = _loop(V, F)
    ref = _reference(V, loop, None, d.frame.front, d.frame.up)
    solver = RicciFlowSolver(V, F)
    settings = [(b, 2.5) for b in bottoms] + [(0.25, lam) for lam in lams if lam != 2.5]
    for bottom, lam in settings:
        a = bottom / 2
        top = 0.5 - bottom
        corners = _split(V, loop, ref, np.array([-a, a, 0.5 - top / 2, 0.5 + top / 2]))
        r = solver.solve(corners, quiet=True)
        uv = r.unit_square()
        ids = {k: int(np.argmin(np.linalg.norm(r.V - np.asarray(p), axis=1))) for k, p in case.landmarks.items()}
        R = np.r_[roi, np.zeros(len(r.V) - len(V), bool)]
        w = vertex_areas(r.V, r.F) * np.where(R, lam, 1.0)
        below = float(w[uv[:, 1] < uv[ids["nose"], 1]].sum() / w.sum())
        t = time.perf_counter()
        mp = measure_preserving_map(r.V, r.F, uv, roi=R, lam=lam, quiet=True)
        yield {"head": case.name, "bottom_side": bottom, "lam": lam, "aspect": float(r.aspect),
               "mass_below_nose": below,
               "conformal_rows": {k: float(1 - uv[i, 1]) for k, i in ids.items()},
               "ot_rows": {k: float(1 - mp.uv[i, 1]) for k, i in ids.items()},
               "ot_columns": {k: float(mp.uv[i, 0]) for k, i in ids.items()},
               "face_share": float(w[R].sum() / w.sum()), "ot_seconds": time.perf_counter() - t}


def main() -> None:
    import make_stress_cases as S
    from bench_stress import emit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ict", type=int, default=3)
    ap.add_argument("--meshes", nargs="*", default=["face.obj", "ninjaHead_Low.obj", "decimated-max.obj"])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    cases = [S.real_base(m) for m in args.meshes] + [S.ict_base(s) for s in range(args.ict)]
    for case in cases:
        for row in measure_head(case):
            emit(row, args.out)


if __name__ == "__main__":
    main()
