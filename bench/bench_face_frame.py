"""The head frame found from the face, on real heads and ICT-FaceKit heads turned at random.

Every human head of ``../shared/data/meshes`` (the Max Planck bust, a scanned face-and-head, a
low-poly game head) and ICT-FaceKit heads (identity and three expressions from the seed) — as
given and turned by ``--rotations`` random rotations (uniform on SO(3)) — and, for the ICT heads,
the kinds a scan arrives as (``--kinds``: face only, closed at the neck, on shoulders in a
shirt, a bust on a plinth) are converted with the defaults at ``--res`` (corner set 0). Each
case prints one JSON line: how the frame was found, up and front taken back to the unturned
head's coordinates, the eye line's angle and the face's centre in the default image (from the
landmarks the finder found, and independently from the true ones: the ICT model's, or marked by
hand on the real heads), the landmark error against the ICT model's 68 (mm), and the seconds.

    python bench/bench_face_frame.py --rotations 20 --ict 10 --res 256 --out bench/results/face_frame/face_frame_256.jsonl
    python bench/face_frame_table.py bench/results/face_frame/face_frame_256.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "data_tools"))

import make_stress_cases as S  # noqa: E402

REAL_HEADS = ("decimated-max.obj", "face.obj", "ninjaHead_Low.obj")
KINDS = {"face_only": S.face_only, "closed_neck": S.closed_neck, "torso": S.with_torso, "plinth": S.with_plinth}


def _ict_truth(seed):
    """The ICT head of ``seed`` (as ``make_stress_cases.ict_base`` builds it) and its 68 landmarks' vertices."""
    from geoface.synth.ict import ict_head, load_ict_model, random_expression

    model = load_ict_model()
    rng = np.random.default_rng(seed)
    h = ict_head(model, seed=seed, expression=random_expression(rng, model.expression_names))
    return h.landmarks


def _tilt_and_center(pix, N):
    """(eye line degrees, the eyes' and mouth's centre column offset over the width) from
    ``{name: (row, col, d)}`` pixels of the eyes and the nose (no mouth: the nose for it)."""
    if not all(k in pix for k in ("eye_right", "eye_left", "nose")):
        return None, None
    (r1, c1, _), (r2, c2, _) = pix["eye_right"], pix["eye_left"]
    tilt = float(np.degrees(np.arctan2(-(r2 - r1), c2 - c1)))
    center = float((0.25 * (c1 + c2) + 0.5 * pix["nose"][1]) / (N - 1) - 0.5)
    return tilt, center


def run_case(case, base, res, lm_idx, look=True) -> dict:
    from geoface.mesh.io import Mesh
    from geoface.pipeline import ConvertOptions, convert

    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        try:
            m = convert(Mesh(case.V, case.F), Path(tmp) / "out", ConvertOptions(res=res, augment=1, find_face=look), quiet=True)
        except Exception as e:  # a failed case is a row of the table, not the end of the run
            return {"ok": False, "error": f"{type(e).__name__}: {e}", "seconds": time.perf_counter() - t}
        seconds = time.perf_counter() - t
        truth = S.landmark_pixels(Path(tmp) / "out", case.landmarks, subpixel=True) if case.landmarks else {}
    fr, st = m["frame"], m["sets"][0]
    Rb = case.R  # x_case = s R x_base + t: directions back to the base with R^T
    row = {"ok": True, "seconds": seconds, "kind_found": fr["kind"], "how": fr["how"], "certain": fr["certain"],
           "up": (Rb.T @ np.asarray(fr["up"])).tolist(), "front": (Rb.T @ np.asarray(fr["front"])).tolist(),
           "face_found": "face" in m, "face_seconds": fr["cues"].get("face_seconds"),
           "face_confidence": fr["cues"].get("face_confidence"), "face_source": fr["cues"].get("face_source"),
           "eye_line_found": (st.get("face_pixels") or {}).get("eye_line_degrees"),
           "center_found": (st.get("face_pixels") or {}).get("center_offset"),
           "hausdorff": st["reconstruction"]["hausdorff"], "face_hausdorff": st["reconstruction"].get("roi_hausdorff")}
    tilt, center = _tilt_and_center(truth, res)
    row.update(eye_line_true=tilt, center_true=center)
    if lm_idx is not None and "face" in m and m["face"]["source"] == "face mesh":
        from geoface.rotations import upright_rotation

        stored = upright_rotation(fr["up"], fr["front"])
        P = np.array([[np.nan if x is None else x for x in p] for p in m["face"]["points"]]) @ stored  # back to the input
        T = case.V[lm_idx]
        d = np.linalg.norm(P - T, axis=1) / case.s * 10.0  # ICT is in cm; mm
        row.update(landmark_mm_all=float(np.nanmean(d)), landmark_mm_inner=float(np.nanmean(d[17:])),
                   landmark_mm_jaw=float(np.nanmean(d[:17])))
    return row


def cases(args):
    for name in args.meshes:
        base = S.real_base(name)
        yield name, "base", base, None
    for seed in range(args.ict):
        base = S.ict_base(seed)
        lm = _ict_truth(seed)
        yield f"ict{seed}", "base", base, lm
        for kind in args.kinds:
            if kind in ("torso", "plinth", "closed_neck") or kind == "face_only":
                v = KINDS[kind](base)
                # the truth's vertices: face_only renumbers; the others keep the head's vertices first
                idx = None
                if kind == "face_only":
                    from scipy.spatial import cKDTree

                    idx = cKDTree(v.V).query(base.V[lm])[1]
                elif kind == "closed_neck":
                    idx = lm
                yield f"ict{seed}", kind, v, idx


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rotations", type=int, default=20)
    ap.add_argument("--ict", type=int, default=10)
    ap.add_argument("--meshes", nargs="*", default=list(REAL_HEADS))
    ap.add_argument("--kinds", nargs="*", default=[], choices=list(KINDS))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--no-look", action="store_true", help="also convert each unturned case without looking for the face")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    out = a.out.open("a") if a.out else None
    try:
        for mesh, kind, base, lm in cases(a):
            for k in range(a.rotations + 1):
                case = base if k == 0 else S.turned(base, 100 + k)
                row = {"mesh": mesh, "kind": kind, "rotation": k, "res": a.res, "vertices": int(len(case.V))}
                row.update(run_case(case, base, a.res, lm))
                if k == 0 and a.no_look:
                    r2 = run_case(case, base, a.res, None, look=False)
                    row["seconds_without_looking"] = r2["seconds"]
                line = json.dumps(row)
                print(line, flush=True)
                if out:
                    out.write(line + "\n")
                    out.flush()
    finally:
        if out:
            out.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
