"""Write the small copy of the ICT-FaceKit model that the tests use (tests/data/ict_facekit/).

Keeps only the skin surface (face, head and neck: polygons 0-11143), the first 8 identity
modes and 8 expression blendshapes, in the layout of the full ``ict_facekit.npz`` (so
``geoface.synth.ict`` reads both), plus the landmarks.

    python data_tools/make_ict_small.py [../shared/data/ict_facekit/ict_facekit.npz]
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
KEEP_EXPRESSIONS = ["jawOpen", "mouthSmile_L", "mouthSmile_R", "eyeBlink_L", "eyeBlink_R", "browInnerUp_L", "mouthFunnel",
                    "cheekPuff_L"]


def main(src: Path) -> None:
    z = np.load(src, allow_pickle=False)
    faces = z["faces"][:11144]
    used = np.unique(faces[faces >= 0])
    remap = np.full(len(z["neutral"]), -1, np.int64)
    remap[used] = np.arange(len(used))
    faces_c = np.where(faces >= 0, remap[np.maximum(faces, 0)], -1).astype(np.int32)
    names = [str(x) for x in z["expression_names"]]
    ex = [names.index(n) for n in KEEP_EXPRESSIONS]
    lm = np.asarray(json.loads(src.with_name("landmarks.json").read_text())["multi_pie_68"], np.int64)
    out = REPO / "tests" / "data" / "ict_facekit"
    out.mkdir(parents=True, exist_ok=True)
    # vertex ids below FACE_VERTICES (9409) are the face area in the full model; the head
    # surface keeps its vertices in their order, so the face area stays a prefix
    assert (used[: 9409] == np.arange(9409)).all()
    np.savez_compressed(
        out / "ict_facekit_head_small.npz", neutral=z["neutral"][used], faces=faces_c, uv=z["uv"], face_uv=z["face_uv"][:11144],
        identity_modes=z["identity_modes"][:8][:, used], identity_names=z["identity_names"][:8],
        expression_modes=z["expression_modes"][ex][:, used], expression_names=np.array(KEEP_EXPRESSIONS),
        landmarks=remap[lm])
    shutil.copy(src.with_name("LICENSE"), out / "LICENSE")
    print(f"wrote {out / 'ict_facekit_head_small.npz'}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO.parent / "shared" / "data" / "ict_facekit" / "ict_facekit.npz")
