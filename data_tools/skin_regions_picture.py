"""The regional-skin picture of docs/textures.md: albedo, micronormal and specular of two people
on the ICT-FaceKit face tile, each with a close-up of the mouth and nose.

    python data_tools/skin_regions_picture.py docs/images/skin_regions.jpg [--res 1024] [--tile 256] [--seeds 1 6]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    import cv2
    import numpy as np

    from geoface.skin.regions import ict_uv_regions
    from geoface.skin.render import skin_maps

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--res", type=int, default=1024)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 6])
    ap.add_argument("--tile", type=int, default=320, help="side of each picture tile in pixels")
    a = ap.parse_args()
    regions = ict_uv_regions(a.res)
    R, T = a.res, a.tile
    crop = (slice(int(0.30 * R), int(0.62 * R)), slice(int(0.34 * R), int(0.66 * R)))  # nose and mouth
    rows = []
    for seed in a.seeds:
        m = skin_maps(R, seed, regions=regions)
        tiles = []
        for img in (m.albedo, m.micronormal, np.repeat(m.specular, 3, -1)):
            u8 = (np.clip(img, 0, 1)[..., ::-1] * 255).astype(np.uint8)
            tiles += [cv2.resize(u8, (T, T), interpolation=cv2.INTER_AREA),
                      cv2.resize(u8[crop], (T, T), interpolation=cv2.INTER_AREA)]
        rows.append(np.concatenate(tiles, 1))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), np.concatenate(rows, 0), [cv2.IMWRITE_JPEG_QUALITY, 88])
    return 0


if __name__ == "__main__":
    sys.exit(main())
