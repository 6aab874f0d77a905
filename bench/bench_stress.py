"""``geoface convert`` on the stress cases of ``data_tools/make_stress_cases.py``; one JSON line
per case and resolution.

Every case is written to a file and read back as a user's would be, then converted with the
defaults (``--up auto``, ``--roi face``, λ = 2.5) and ``--augment`` corner sets.  Per case:
whether it converted, the corner sets that failed, the frame found (``up``, ``front``, how sure)
and its angle to the truth, the conformal factor's log range, Ricci-flow iterations and
intrinsic flips, the OT path, stages and iterations, the residual reached, flipped triangles,
whole and face Hausdorff distances (of the bbox diagonal; the face: the ROI), the face-pixel
share, seconds, and where the nose, eyes and chin land in the default image (set 0) with what
is wrong there (``upright_problems``: empty when the face is upright and centred).

    python bench/bench_stress.py [--res 128 256] [--augment 8] [--ict 10 --ict-variants 1] [--meshes face.obj]
        [--kinds axes fins ...] [--conventions y-up z-up+x] [--out results.jsonl]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "data_tools"))


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def run_case(case, res: int, augment: int, tmp: Path, blend: float | None = None, feature: float | None = None) -> dict:
    import make_stress_cases as S

    from geoface.errors import GeofaceError
    from geoface.mesh.io import load_mesh
    from geoface.pipeline import ConvertOptions, convert

    file = case.save(tmp)
    mesh = load_mesh(tmp / file)
    records: list = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    h = Keep(level=logging.WARNING)
    logging.getLogger("geoface").addHandler(h)
    t = time.perf_counter()
    out = {"case": case.name, "base": case.base, "kind": case.kind, "convention": case.convention, "res": res,
           "vertices": int(len(mesh.V)), "faces": int(len(mesh.F))}
    try:
        given = {k: v for k, v in (("blend", blend), ("feature", feature)) if v is not None}
        opts = ConvertOptions(res=res, augment=augment, **given)
        m = convert(mesh, tmp / "out", opts, quiet=True)
    except GeofaceError as e:
        out.update(ok=False, error=str(e), seconds=time.perf_counter() - t)
        return out
    finally:
        logging.getLogger("geoface").removeHandler(h)
    out["seconds"] = time.perf_counter() - t
    sets = m["sets"]
    out.update(ok=True, sets=len(sets), failed_sets=[f["corner_set"] for f in m["failed_sets"]],
               failures=[f["error"] for f in m["failed_sets"]], warnings=records,
               up=m["up"], front=m["front"], up_error_deg=_angle(m["up"], case.up), front_error_deg=_angle(m["front"], case.front),
               frame=m.get("frame", {}))
    st0 = sets[0]
    out["log_conformal_range"] = max(s["ricci"]["log_conformal_factor_range"] for s in sets)
    out["ricci_iterations"] = max(s["ricci"]["iterations"] for s in sets)
    out["intrinsic_flips"] = max(s["ricci"]["intrinsic_flips"] for s in sets)
    out["ot_paths"] = sorted({s["ot"]["path"] for s in sets})
    out["ot_solvers"] = sorted({s["ot"].get("solver", "newton") for s in sets})
    out["ot_iterations"] = max(s["ot"]["iterations"] for s in sets)
    out["ot_stages"] = max(s["ot"]["stages"] for s in sets)
    out["ot_residual"] = max(s["ot"]["residual"] for s in sets)
    out["flipped"] = max(s["distortion"]["flipped"] for s in sets)
    out["hausdorff"] = max(s["reconstruction"]["hausdorff"] for s in sets)
    out["hausdorff_set0"] = st0["reconstruction"]["hausdorff"]
    face = [s["reconstruction"].get("face_hausdorff") for s in sets]
    out["face_hausdorff"] = max(face) if all(f is not None for f in face) else None
    out["roi_pixel_share"] = st0.get("roi_pixel_share")
    out["blend"] = st0["ot"].get("blend") if "ot" in st0 else None
    out["feature"] = st0["ot"].get("feature") if "ot" in st0 else None
    if case.landmarks:
        folder = tmp / "out" / ("aug0" if augment > 1 else "")
        pix = S.landmark_pixels(folder, case.landmarks)
        out["landmark_pixels"] = {k: v[:2] for k, v in pix.items()}
        out["upright_problems"] = S.upright_problems(pix, res)
    return out


def emit(row: dict, out: Path | None) -> None:
    """Print one JSON line, and append it to ``out`` when given."""
    line = json.dumps(row, default=float)
    print(line, flush=True)
    if out:
        with open(out, "a") as fh:
            fh.write(line + "\n")


def main() -> None:
    import make_stress_cases as S

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, nargs="+", default=[128])
    ap.add_argument("--augment", type=int, default=8)
    ap.add_argument("--ict", type=int, default=1, help="ICT heads (seeds 0..N-1)")
    ap.add_argument("--ict-variants", type=int, default=None, help="only the first N ICT heads get the stress variants")
    ap.add_argument("--meshes", nargs="*", default=list(S.REAL))
    ap.add_argument("--kinds", nargs="*", default=list(S.CASE_KINDS), choices=S.CASE_KINDS)
    ap.add_argument("--conventions", nargs="*", default=list(S.CONVENTIONS) + [S.TILTED],
                    help="comma-separated too, for names that start with '-': --conventions=-x-up,-y-up")
    ap.add_argument("--only", nargs="*", default=None, help="case names to run (default all)")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    args = ap.parse_args()
    args.conventions = [c for item in args.conventions for c in item.split(",") if c]
    import os

    os.environ.setdefault("GEOFACE_QUIET", "1")
    for case in S.stress_cases(meshes=args.meshes, ict=range(args.ict), kinds=args.kinds, conventions=args.conventions,
                               ict_variants=args.ict_variants):
        if args.only and case.name not in args.only:
            continue
        for res in args.res:
            with tempfile.TemporaryDirectory() as tmp:
                r = run_case(case, res, args.augment, Path(tmp))
            emit(r, args.out)


if __name__ == "__main__":
    main()
