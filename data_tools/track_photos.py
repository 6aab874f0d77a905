"""Real photos → the ICT-FaceKit head → a UV texture: the picture and figures of docs/track.md.

Three real photographs that installed packages ship (nothing is downloaded): scikit-image's
``astronaut`` (Eileen Collins, NASA, public domain) and ``camera`` (the "cameraman", grey), and
Matplotlib's ``grace_hopper.jpg`` (US Navy, public domain). For each: MediaPipe finds the face
(detector confidence) and its 68 landmarks; the ICT head (identity, expression, pose, focal) is
fitted to them; the held-out error is each landmark's distance to the head fitted without it
(4 interleaved folds, :func:`geoface.synth.ict_fit.heldout_errors`); the photo is projected into
the head's UV layout and what the camera did not see is inpainted. One JSON line per photo, and a
picture: the photo with the fitted head over it (tracked landmarks green, the head's red), the UV
texture, and the textured head from the front and at 45°.

    python data_tools/track_photos.py [--out bench/results/ict_fit/photos.jsonl] [--picture docs/images/track_photos.jpg]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def photos() -> dict:
    """name → (H, W, 3) uint8 RGB of the three shipped photos."""
    import matplotlib
    from skimage import data

    from geoface.images import read_image

    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    return {"astronaut (scikit-image)": data.astronaut(),
            "grace_hopper (Matplotlib)": np.round(read_image(hopper) * 255).astype(np.uint8),
            "cameraman (scikit-image, grey)": np.repeat(data.camera()[..., None], 3, 2)}


def textured_views(head, tex, size: int):
    """The textured head (model coordinates, cm, y up, facing +z) from the front and at 45°."""
    from geoface.camera import look_at
    from geoface.nn.mesh_render import render_mesh

    c = head.V.mean(0)
    r = 2.4 * np.linalg.norm(head.V.max(0) - head.V.min(0)) / 2
    out = []
    for az in (0.0, 45.0):
        a = np.radians(az)
        eye = c + r * np.array([np.sin(a), 0.0, np.cos(a)])
        cam = look_at(eye, c, width=size, height=size, fov_y_deg=30.0)
        out.append(render_mesh(head.V, head.F, cam, uv=head.UV, fuv=head.FUV, texture=tex, background=(1, 1, 1),
                               supersample=2).rgb)
    return out


def main() -> int:
    import cv2

    from geoface.camera import Camera
    from geoface.mesh.io import Mesh
    from geoface.nn.mesh_render import render_mesh
    from geoface.synth.ict import load_ict_model
    from geoface.synth.ict_fit import fit_landmarks, heldout_errors, project
    from geoface.track import track_frames
    from geoface.uvmap.inpaint import inpaint
    from geoface.uvmap.project import project_views

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="append the JSON lines here too")
    ap.add_argument("--picture", type=Path, default=None)
    ap.add_argument("--tile", type=int, default=256)
    a = ap.parse_args()
    ict = load_ict_model()
    rows, tiles = [], []
    for name, img in photos().items():
        t0 = time.perf_counter()
        tr = track_frames([img], masks=False, video=False, confidence=True, quiet=True)
        t_track = time.perf_counter() - t0
        H, W = img.shape[:2]
        L = tr.landmarks[0]
        t0 = time.perf_counter()
        fit = fit_landmarks(ict, L, (W, H))
        t_fit = time.perf_counter() - t0
        held = heldout_errors(ict, L, (W, H))
        iod = float(np.linalg.norm(L[36] - L[45]))
        head = fit.head(ict)
        mesh = Mesh(head.V, head.F, UV=head.UV, FUV=head.FUV)
        cam = Camera.from_K(fit.K, fit.R, fit.t, W, H)
        proj = project_views(mesh, [img.astype(np.float64) / 255], [cam], size=512)
        seen = proj.weight > 0
        tex = inpaint(proj.texture, seen)
        row = {"bench": "track_photos", "photo": name, "size": [W, H], "found": bool(tr.found[0]),
               "confidence": round(float(tr.confidence[0]), 3), "interocular_px": round(iod, 1),
               "fit_rms_px": round(fit.rms_px, 2), "heldout_mean_px": round(float(held.mean()), 2),
               "heldout_p95_px": round(float(np.percentile(held, 95)), 2),
               "heldout_mean_iod": round(float(held.mean()) / iod, 4), "focal_px": round(fit.focal, 1),
               "uv_seen": round(float(seen.mean()), 3), "track_s": round(t_track, 2), "fit_s": round(t_fit, 2)}
        print(json.dumps(row), flush=True)
        rows.append(row)
        if a.picture is None:
            continue
        # the fitted head over the photo: shaded grey at half opacity, the landmarks on top
        r = render_mesh(head.V, head.F, cam, colors=np.full((len(head.V), 3), 0.8), shading="headlight")
        over = img.astype(np.float64) / 255
        al = 0.55 * r.alpha[..., None]
        over = over * (1 - al) + r.rgb * al
        over = np.round(over * 255).astype(np.uint8)[:, :, ::-1].copy()
        s = max(1, round(W / 256))
        for p in L:
            cv2.circle(over, (int(round(p[0])), int(round(p[1]))), s + 1, (0, 200, 0), -1)
        for p in project(head.V[head.landmarks], fit.R, fit.t, fit.focal, fit.centre):  # the head's own landmarks
            cv2.circle(over, (int(round(p[0])), int(round(p[1]))), s, (0, 0, 255), -1)
        T = a.tile
        x0, y0 = L.min(0)
        x1, y1 = L.max(0)
        cx, cy, half = (x0 + x1) / 2, (y0 + y1) / 2, 0.85 * max(x1 - x0, y1 - y0)
        crop = over[max(0, int(cy - half)):min(H, int(cy + half)), max(0, int(cx - half)):min(W, int(cx + half))]
        views = textured_views(head, tex, T)
        cells = [cv2.resize(crop, (T, T), interpolation=cv2.INTER_AREA),
                 cv2.resize(np.round(tex * 255).astype(np.uint8)[:, :, ::-1], (T, T), interpolation=cv2.INTER_AREA)]
        cells += [np.round(v * 255).astype(np.uint8)[:, :, ::-1] for v in views]
        gap = np.full((T, 4, 3), 255, np.uint8)
        line = cells[0]
        for c in cells[1:]:
            line = np.concatenate([line, gap, c], 1)
        tiles.append(line)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        with open(a.out, "a") as fh:
            for row in rows:
                fh.write(json.dumps(row) + "\n")
    if a.picture is not None:
        gap = np.full((4, tiles[0].shape[1], 3), 255, np.uint8)
        pic = tiles[0]
        for t in tiles[1:]:
            pic = np.concatenate([pic, gap, t], 0)
        a.picture.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(a.picture), pic, [cv2.IMWRITE_JPEG_QUALITY, 88])
        print(f"picture: {a.picture}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("GEOFACE_QUIET", "1")
    sys.exit(main())
