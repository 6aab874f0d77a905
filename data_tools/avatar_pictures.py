"""Pictures of the avatars on ICT-FaceKit captures for the docs, each frame beside its truth.

    python data_tools/avatar_pictures.py hmd MODEL_DIR USAGE_DIR OUT.jpg [--frames 5 20 40] [--poses landmarks]
        [--error-poses landmarks landmarks+image file --gain 4]
    python data_tools/avatar_pictures.py talk MODEL_DIR DATA_DIR OUT.jpg [--count 4]

* ``hmd``: per chosen usage frame, a column of the input (headset on), the restored frame (the
  avatar pasted into the headset's region, poses as ``--poses`` says), the ground truth (the
  same frame rendered without the headset) and the avatar's own whole render; with
  ``--error-poses``, then for each of those pose sources the restored frame's error against the
  ground truth where the occluded region is scored (face pixels under the headset; absolute
  difference times ``--gain``); a source ``landmarks+image`` is the landmark poses aligned with
  the image (``--pose-align 20``);
* ``talk``: held-out frames of a THGS model (the last fraction its training left out, those with
  the widest range of mouth opening), the render above the real frame.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _grid(rows, tile: int):
    import cv2
    import numpy as np

    def t(img):
        img = (np.clip(img, 0, 1) * 255).astype(np.uint8)[..., ::-1]
        return cv2.resize(img, (tile, tile), interpolation=cv2.INTER_AREA if img.shape[0] > tile else cv2.INTER_CUBIC)

    return np.concatenate([np.concatenate([t(im) for im in row], 1) for row in rows], 0)


def _renders(model, video, source: str):
    """The avatar's renders of ``video`` in the poses of ``source`` (``landmarks+image``: the
    landmark poses aligned with the image, 20 steps a frame)."""
    from dataclasses import replace

    from geoface.hfm.usage import remove_hmd

    cfg = model.cfg
    model.cfg = replace(cfg, pose_align=20 if source.endswith("+image") else 0)
    try:
        return remove_hmd(model, video, poses=source.removesuffix("+image"))[0]
    finally:
        model.cfg = cfg


def hmd(a) -> "np.ndarray":
    import numpy as np

    from geoface.hfm.data import load_video
    from geoface.images import read_image
    from geoface.hfm.io import load_hfm

    model = load_hfm(a.model_dir)
    video = load_video(a.data_dir)
    renders = _renders(model, video, a.poses)
    frames = [f for f in a.frames if f < len(video)]
    gt = [read_image(Path(a.data_dir) / "gt" / f"{f:06d}.png") for f in frames]
    restored = [np.where(video.hmd_masks[f][..., None], renders[f], video.frames[f]) for f in frames]
    rows = [[video.frames[f] for f in frames], restored, gt, [renders[f] for f in frames]]
    for source in a.error_poses:
        R = renders if source == a.poses else _renders(model, video, source)
        rows.append([np.abs(R[f] - g) * a.gain * (video.hmd_masks[f] & (g.max(-1) > 0))[..., None]
                     for f, g in zip(frames, gt)])  # where the occluded-region PSNR is scored
    return _grid(rows, a.tile)


def talk(a) -> "np.ndarray":
    import numpy as np

    from geoface.thgs.train import train_heldout_split
    from geoface.thgs.inference import load_thgs, render_frames
    from geoface.thgs.eval import _mouth_rect, mouth_openness
    from geoface.thgs.data import load_talking

    model = load_thgs(a.model_dir)
    data = load_talking(a.data_dir)
    _, te = train_heldout_split(len(data), model.cfg.heldout)
    opening = [mouth_openness(data.frames[t], _mouth_rect(model, data.camera, data.rot[t], data.transl[t])) for t in te]
    order = np.argsort(opening)
    pick = sorted(te[order[np.linspace(0, len(te) - 1, a.count).round().astype(int)]])
    R, _ = render_frames(model, data.camera, data.rot, data.transl, data.expr, data.audio, pick)
    return _grid([list(R), [data.frames[t] for t in pick]], a.tile)


def main() -> int:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("kind", choices=("hmd", "talk"))
    ap.add_argument("model_dir")
    ap.add_argument("data_dir")
    ap.add_argument("out", type=Path)
    ap.add_argument("--frames", type=int, nargs="+", default=[5, 20, 40])
    ap.add_argument("--poses", default="landmarks")
    ap.add_argument("--error-poses", nargs="*", default=[], help="hmd: a row of errors for each of these pose sources")
    ap.add_argument("--gain", type=float, default=4.0, help="hmd: how much the error rows are brightened")
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--tile", type=int, default=192)
    a = ap.parse_args()
    img = hmd(a) if a.kind == "hmd" else talk(a)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    print(f"{a.out}: {img.shape[1]}×{img.shape[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
