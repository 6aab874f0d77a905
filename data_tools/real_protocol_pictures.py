"""The pictures of the avatars' "from your own video" sections: an ICT-FaceKit person rendered
talking, made into a capture by ``geoface capture`` from its frames and sound alone, split by time
and scored as the real clips are (``bench/eval_real_avatars.py ict:SEED``, whose work folder this
reads). One row per held-out frame shown: the input with the headset, HFM-GS's output, THGS's
output, the nearest training frame (baseline a) and the truth. (The real clips' terms keep their
frames out of the repository and its docs.)

    python bench/eval_real_avatars.py ict:13 --work WORK --out bench/results/real_avatars/ict_256.jsonl
    python data_tools/real_protocol_pictures.py WORK/ict_13 [--out docs/images/real_protocol_ict.png]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from geoface.avatar import protocol as P
    from geoface.capture import Capture
    from geoface.hfm import load_hfm
    from geoface.hfm.data import load_video
    from geoface.hfm.usage import remove_hmd
    from geoface.images import save_image
    from geoface.thgs.data import load_talking
    from geoface.thgs.inference import load_thgs, render_frames
    from geoface.thgs.train import train_heldout_split

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", help="the bench's folder of one clip (capture/, split/, hfm_*/, thgs_*/)")
    ap.add_argument("--out", default=str(ROOT / "docs/images/real_protocol_ict.png"))
    ap.add_argument("--frames", type=int, nargs="+", default=None, help="test frames shown (default: three spread)")
    a = ap.parse_args(argv)
    work = Path(a.work)
    test = work / "split" / "test"
    te = Capture(test)
    shown, gt = te.frames(), te.images("gt", rgb=True)
    hmd = (te.images("hmd_masks") > 0.5)[..., None]
    nf, _ = P.nearest_frame(work / "split" / "train", test)
    hfm_dir = sorted(work.glob("hfm_*"))[-1]
    R_hfm, _ = remove_hmd(load_hfm(hfm_dir), load_video(test), poses="file")
    hfm = np.where(hmd, R_hfm, shown)
    thgs_dir = sorted(work.glob("thgs_*"))[-1]
    data = load_talking(work / "capture")
    _, idx = train_heldout_split(len(data), P.TEST_FRACTION)
    model = load_thgs(thgs_dir)
    R_thgs, _ = render_frames(model, data.camera, data.rot, data.transl, data.expr, data.audio, idx)
    pick = a.frames or np.linspace(0, len(gt) - 1, 3).round().astype(int).tolist()
    rows = [np.concatenate([shown[k], hfm[k], R_thgs[k], np.where(hmd[k], nf[k], shown[k]), gt[k]], 1) for k in pick]
    save_image(a.out, np.concatenate(rows, 0))
    print(a.out, "test frames", pick, "columns: input with the headset | HFM-GS | THGS | nearest training frame | truth")
    return 0


if __name__ == "__main__":
    sys.exit(main())
