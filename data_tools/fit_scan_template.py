"""The template of the face finder's frame: the ICT-FaceKit mean head's landmarks as
:func:`geoface.track.scan.scan_landmarks` finds them on renders of it.

The frame of a face (:func:`geoface.track.face3d.face_frame`) is the rotation that takes the
template's landmarks onto the face's. With the model's own 68 landmarks as the template, the mean
head's frame came out 3-4° off its own axes: MediaPipe's points are not the model's (its nose tip
sits lower, its eye corners further in). Here the mean head (no expression) is turned by 12 random
rotations, its landmarks are found in each (9 views) and taken back to the model's frame; their
median is the template, so a head comes out in the model's frame as MediaPipe sees faces. The
same for the face detector's four key points (eyes, nose tip, mouth), which stand in where the
face mesh finds no face.

    python data_tools/fit_scan_template.py            # writes geoface/data/scan_template.json (about a minute)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rotations", type=int, default=12)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    from scipy.spatial.transform import Rotation

    import geoface.track.face3d as f3
    from geoface.synth.ict import load_ict_model
    from geoface.track.scan import scan_landmarks

    out = a.out or f3.TEMPLATE_FILE
    f3.TEMPLATE_FILE = REPO / "no-template.json"  # measure against the model's own landmarks
    f3._template.cache_clear()
    h = load_ict_model().head(None)
    P, K, spread = [], [], []
    for k in range(a.rotations):
        R = Rotation.random(random_state=1000 + k).as_matrix()
        V = h.V @ R.T
        r = scan_landmarks(V, h.F, views=9, source="face mesh")
        q = scan_landmarks(V, h.F, views=9, source="face detector")
        if not (r.found and q.found):
            print(f"rotation {k}: not found ({r.why or q.why})", file=sys.stderr)
            continue
        P.append(r.points @ R)
        K.append(q.keypoints @ R)
        spread.append(r.spread)
    P, K = np.nanmedian(np.stack(P), 0), np.median(np.stack(K), 0)
    truth = h.V[h.landmarks]
    off = np.linalg.norm(P - truth, axis=1)
    doc = {"what": "the ICT-FaceKit mean head's 68 iBUG landmarks and the face detector's 4 key points (right eye, "
                   "left eye, nose tip, mouth) as geoface.track.scan.scan_landmarks finds them, in the model's frame "
                   "(Y up, facing +Z, cm); written by data_tools/fit_scan_template.py",
           "rotations": len(spread), "views": 9, "spread": round(float(np.mean(spread)), 4),
           "offset_from_model_cm": {"inner_mean": round(float(off[17:].mean()), 3), "jaw_mean": round(float(off[:17].mean()), 3)},
           "points": np.round(P, 4).tolist(), "keypoints": np.round(K, 4).tolist()}
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps({k: v for k, v in doc.items() if k not in ("points", "keypoints")}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
