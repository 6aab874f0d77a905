"""The pictures of docs/video.md: an ICT-FaceKit person rendered talking (``talk synth``'s
generator, 512², the renderer's truth unused), made into a capture by ``geoface capture`` from
its frames alone, and its overlay: frames beside the tracked head drawn over them. (The real
clips' terms keep their frames out of the repository and its docs.)

    python data_tools/capture_pictures.py [--out docs/images/capture_overlay_ict.png]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from geoface.avatar.clip import capture_clip
    from geoface.images import save_image
    from geoface.thgs.ict import make_ict_talking
    from geoface.video import read_video

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs/images/capture_overlay_ict.png"))
    ap.add_argument("--seed", type=int, default=13)
    a = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="geoface_capture_pics_"))
    talk = make_ict_talking(work / "talk", seconds=2.0, res=512, seed=a.seed, emote=1.0, quiet=True)
    cap = capture_clip(talk / "frames", work / "cap", res=384, fps=25, audio=talk / "audio.wav", quiet=True)
    frames, _ = read_video(cap.folder / "overlay.mp4")
    pick = np.linspace(0, len(frames) - 1, 3).round().astype(int)
    grid = np.concatenate([frames[k] for k in pick], 0)  # three rows: frame | frame with the tracked head
    save_image(a.out, grid[::2, ::2])
    print(a.out, cap)
    return 0


if __name__ == "__main__":
    sys.exit(main())
