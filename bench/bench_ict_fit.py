"""Fitting the ICT model to 68 landmarks (geoface.synth.ict_fit) on synthetic photos: pose and
landmark errors and time, with the focal length known and estimated. One JSON line per photo,
then a summary per setting.

    python bench/bench_ict_fit.py --photos 20 --noise 0.5
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from geoface.synth.ict import load_ict_model, random_expression  # noqa: E402
from geoface.synth.ict_fit import fit_landmarks, project  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photos", type=int, default=20)
    ap.add_argument("--noise", type=float, default=0.5, help="landmark noise, pixels (standard deviation per axis)")
    ap.add_argument("--size", type=int, default=1024, help="image side")
    ap.add_argument("--seed", type=int, default=100, help="first photo's seed (the tests use seeds below 10)")
    a = ap.parse_args()
    m = load_ict_model()
    lm = m.view("skin").landmarks
    W = H = a.size
    rows = {"known": [], "estimated": []}
    for s in range(a.seed, a.seed + a.photos):
        rng = np.random.default_rng(s)
        V = m.shape(rng.standard_normal(m.n_identities), random_expression(rng, m.expression_names, count=2, strength=0.7), "skin")
        ypr = rng.uniform([-30, -15, -10], [30, 15, 10])
        R = Rotation.from_euler("yxz", ypr, degrees=True).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        f = rng.uniform(1.5, 3.0) * W
        t = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), f / W * 35])
        truth = project(V[lm], R, t, f, (W / 2, H / 2))
        noisy = truth + rng.normal(0, a.noise, truth.shape)
        for setting, focal in (("known", f), ("estimated", None)):
            t0 = time.perf_counter()
            fit = fit_landmarks(m, noisy, (W, H), focal=focal)
            sec = time.perf_counter() - t0
            head = fit.head(m)
            err = np.linalg.norm(project(head.V[head.landmarks], fit.R, fit.t, fit.focal, fit.centre) - truth, axis=1)
            row = {"case": "photo", "focal": setting, "seed": s, "yaw_pitch_roll": [round(float(x), 1) for x in ypr],
                   "rotation_error_deg": float(np.degrees(np.linalg.norm(Rotation.from_matrix(fit.R @ R.T).as_rotvec()))),
                   "landmark_error_mean_px": float(err.mean()), "landmark_error_max_px": float(err.max()),
                   "focal_ratio": fit.focal / f, "seconds": sec}
            rows[setting].append(row)
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
    for setting, rs in rows.items():
        rot = np.array([r["rotation_error_deg"] for r in rs])
        print(json.dumps({"case": "summary", "focal": setting, "photos": len(rs), "noise_px": a.noise,
                          "rotation_error_deg_median": round(float(np.median(rot)), 3), "rotation_error_deg_max": round(float(rot.max()), 3),
                          "share_within_2deg": round(float((rot < 2).mean()), 3),
                          "landmark_error_mean_px": round(float(np.mean([r["landmark_error_mean_px"] for r in rs])), 3),
                          "landmark_error_max_px": round(float(np.max([r["landmark_error_max_px"] for r in rs])), 3),
                          "seconds_median": round(float(np.median([r["seconds"] for r in rs])), 2)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
