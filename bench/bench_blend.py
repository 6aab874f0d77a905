"""Choosing OT's target measure: ``--blend`` β and ``--feature`` γ on validation heads, then
the test cases.

``ν_i ∝ (λ_i · area_i)^(1-β) · (conformal area_i)^β · (1 + γ sharpness_i)``
(:mod:`geoface.param.measure`).  Per case, β and γ, one JSON line from ``bench_stress.run_case``: whole and face Hausdorff (worst of
the corner sets), the face's pixel share, the OT path, seconds.  The validation split is four
ICT heads the stress table does not use (identities 20 and 21 as they are, 22 closed at the
neck, 23 cut to a face-only scan); β is chosen there; the test split is the stress table's
bases (the nine meshes of ``../shared/data/meshes``, ICT heads 0 and 1, ICT 0 closed at the neck
and face-only), in Y-up.

    python bench/bench_blend.py --split val --blend 0 0.1 0.2 0.3 --out bench/results/blend/val_512.jsonl
    python bench/bench_blend.py --split test --blend 0 0.2 --out bench/results/blend/test_512.jsonl
    python bench/bench_blend.py --table bench/results/blend/val_512.jsonl bench/results/blend/test_512.jsonl
    python bench/bench_blend.py --split val --blend 0.1 --feature 0 2 4 8 --out bench/results/blend/feature_val_512.jsonl

Without ``--feature`` the cases run with γ = 0, the measure of the β runs (before γ existed).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
sys.path.insert(0, str(REPO / "data_tools"))


def cases(split: str) -> list[tuple[str, object]]:
    """(name, builder) per case: a case is built only where it is run."""
    import make_stress_cases as S

    if split == "val":
        return [("ict20", lambda: S.ict_base(20)), ("ict21", lambda: S.ict_base(21)),
                ("ict22_closed_neck", lambda: S.closed_neck(S.ict_base(22))),
                ("ict23_face_only", lambda: S.face_only(S.ict_base(23)))]
    return [(Path(n).stem, lambda n=n: S.real_base(n)) for n in S.REAL] + [
        ("ict0", lambda: S.ict_base(0)), ("ict1", lambda: S.ict_base(1)),
        ("ict0_closed_neck", lambda: S.closed_neck(S.ict_base(0))), ("ict0_face_only", lambda: S.face_only(S.ict_base(0)))]


def _one(job) -> dict:
    split, idx, blend, feature, res, augment = job
    os.environ.setdefault("GEOFACE_QUIET", "1")
    import bench_stress

    case = cases(split)[idx][1]()
    with tempfile.TemporaryDirectory() as tmp:
        r = bench_stress.run_case(case, res, augment, Path(tmp), blend=blend, feature=feature)
    keep = ("case", "res", "ok", "sets", "failed_sets", "flipped", "ot_paths", "hausdorff", "face_hausdorff",
            "roi_pixel_share", "seconds", "landmark_pixels", "upright_problems", "error")
    return {"split": split, "blend": blend, "feature": feature, **{k: r[k] for k in keep if k in r}}


def table(paths) -> str:
    rows = [json.loads(line) for p in paths for line in Path(p).read_text().splitlines() if line.strip()]
    for r in rows:
        r.setdefault("feature", 0.0)  # runs from before γ: the paper's masses
    settings = sorted({(r["blend"], r["feature"]) for r in rows})
    out = ["| split | β | γ | cases | whole Hausdorff: median / worst | ≤ 0.5% | face: median / worst | ≤ 0.2% | face pixels (median) | flips |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    import numpy as np

    for split in ("val", "test"):
        for b, g in settings:
            rs = [r for r in rows if r["split"] == split and (r["blend"], r["feature"]) == (b, g) and r.get("ok")]
            if not rs:
                continue
            h = np.array([r["hausdorff"] for r in rs]) * 100
            f = np.array([r["face_hausdorff"] for r in rs if r.get("face_hausdorff") is not None]) * 100
            px = np.median([r["roi_pixel_share"] for r in rs]) * 100
            out.append(f"| {split} | {b:g} | {g:g} | {len(rs)} | {np.median(h):.2f}% / {h.max():.2f}% | {(h <= 0.5).sum()} of {len(h)} | "
                       f"{np.median(f):.2f}% / {f.max():.2f}% | {(f <= 0.2).sum()} of {len(f)} | {px:.0f}% | "
                       f"{max(r['flipped'] for r in rs)} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=("val", "test"), default="val")
    ap.add_argument("--blend", type=float, nargs="+", default=[0.0, 0.1, 0.2, 0.3])
    ap.add_argument("--feature", type=float, nargs="+", default=[0.0])
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--augment", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="case names to run (default all)")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    ap.add_argument("--table", nargs="+", default=None, help="print the summary table of these result files and stop")
    args = ap.parse_args()
    import bench_stress

    if args.table:
        print(table(args.table))
        return
    names = [n for n, _ in cases(args.split)]
    idx = [i for i, n in enumerate(names) if not args.only or n in args.only]
    jobs = [(args.split, i, b, g, args.res, args.augment) for b in args.blend for g in args.feature for i in idx]
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(_one, jobs):
            bench_stress.emit(r, args.out)


if __name__ == "__main__":
    main()
