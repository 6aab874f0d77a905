"""The held-out-face picture of docs/textures.md: for test faces of ``bench/eval_texture.py``,
the photo, then albedo, micronormal and specular as the GDE upsampled gives them, as GDE +
HFDR gives them, and the truth; a second row per face shows a close-up (cheek and nose).

    python data_tools/texture_picture.py EVAL_OUT docs/images/texture_heldout.jpg [--faces 0 3] [--tile 256]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    import cv2
    import numpy as np

    from geoface.texture.model import TextureModel, load_sample, reconstruct

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("eval_out", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--faces", type=int, nargs="+", default=[0, 3])
    ap.add_argument("--tile", type=int, default=256)
    a = ap.parse_args()
    model = TextureModel.load(a.eval_out / "model_full")
    files = sorted((a.eval_out / "test").glob("*.npz"))
    T = a.tile

    def tile(img, box=None):
        img = np.clip(img if img.shape[-1] == 3 else np.repeat(img, 3, -1), 0, 1)
        img = img if box is None else img[box]
        return cv2.resize((img[..., ::-1] * 255).astype(np.uint8), (T, T), interpolation=cv2.INTER_AREA
                          if img.shape[0] > T else cv2.INTER_NEAREST)

    rows = []
    for f in a.faces:
        d = load_sample(files[f])
        up = reconstruct(model, d["photo"], refine=False)
        hf = reconstruct(model, d["photo"], refine=True)
        truth = {"albedo": d["maps"][..., 0:3], "micronormal": d["maps"][..., 3:6], "specular": d["maps"][..., 6:7]}
        ys, xs = np.nonzero(d["mask"])
        cy, cx = int(np.median(ys)), int(np.median(xs))
        h = max(16, (ys.max() - ys.min()) // 6)
        boxes = [(slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1)),
                 (slice(cy - h, cy + h), slice(cx - h, cx + h))]  # the face; a close-up of its middle
        for box in boxes:
            m = d["mask"][..., None]
            tiles = [tile(d["photo"], box)]
            for name, gamma in (("albedo", 1 / 2.2), ("micronormal", 1.0), ("specular", 1.0)):
                for src in (up, hf, truth):
                    tiles.append(tile(np.where(m, src[name], 0) ** gamma, box))
            rows.append(np.concatenate(tiles, 1))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), np.concatenate(rows, 0), [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
