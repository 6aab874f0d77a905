"""Render screenshots of the procedural head (off-screen, pyvista) for visual checks.

Usage::

    python data_tools/render_head.py --out /tmp/head_shots --n 50000 --seed 0
    python data_tools/render_head.py --expressions smile jaw_open --views front three_quarter side
    python data_tools/render_head.py --texture        # use the UV texture instead of vertex colours

Writes one PNG per (expression, view) plus a contact sheet ``sheet.png``.  pyvista and
pillow are needed (``pip install 'geoface[viz,extra]'``); a harmless X-server warning may print.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

VIEWS = {
    "front": (0.0, 0.0, 1.0),
    "three_quarter": (0.7, 0.1, 0.7),
    "side": (1.0, 0.0, 0.0),
    "back": (0.0, 0.2, -1.0),
    "below": (0.0, -0.8, 0.6),
    "top": (0.0, 1.0, 0.05),
    "three_quarter_right": (-0.7, 0.1, 0.7),
}


def render(head, view="front", size=512, zoom=1.0, focus=(0.0, -0.03, 0.0), use_texture=False, edges=False):
    """Render one view of a :class:`~geoface.synth.head.SynthHead`; returns an (size, size, 3) uint8 image."""
    import pyvista as pv

    faces = np.hstack([np.full((len(head.F), 1), 3), head.F]).ravel()
    mesh = pv.PolyData(head.V, faces)
    pl = pv.Plotter(off_screen=True, window_size=(size, size))
    pl.set_background("white")
    kw = dict(smooth_shading=True, show_edges=edges, edge_color="gray", specular=0.15, diffuse=0.85, ambient=0.18)
    if use_texture:
        mesh.active_texture_coordinates = head.UV
        pl.add_mesh(mesh, texture=pv.Texture(np.ascontiguousarray(head.texture)), **kw)
    else:
        mesh.point_data["rgb"] = (np.clip(head.colors, 0, 1) * 255).astype(np.uint8)
        pl.add_mesh(mesh, scalars="rgb", rgb=True, **kw)
    d = np.asarray(VIEWS[view], dtype=float)
    d /= np.linalg.norm(d)
    c = np.asarray(focus, dtype=float)
    pl.camera.position = tuple(c + 0.68 / zoom * d)
    pl.camera.focal_point = tuple(c)
    pl.camera.up = (0.0, 1.0, 0.0)
    pl.camera.view_angle = 30.0
    img = pl.screenshot(return_img=True)
    pl.close()
    return img


def main(argv=None):
    from PIL import Image

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from geoface.synth.head import EXPRESSION_NAMES, HeadModel

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/head_shots")
    ap.add_argument("--n", type=int, default=50000)
    ap.add_argument("--seed", type=int, nargs="+", default=[0], help="one row block per seed (identity)")
    ap.add_argument("--size", type=int, default=480)
    ap.add_argument("--zoom", type=float, default=1.0)
    ap.add_argument("--face", action="store_true", help="close-up of the face")
    ap.add_argument("--texture", action="store_true")
    ap.add_argument("--edges", action="store_true")
    ap.add_argument("--views", nargs="+", default=["front", "three_quarter", "side"], choices=sorted(VIEWS))
    ap.add_argument("--expressions", nargs="+", default=["neutral"], choices=["neutral", *EXPRESSION_NAMES])
    ap.add_argument("--prefix", default="head")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    zoom, focus = (1.8, (0.0, -0.03, 0.06)) if args.face else (args.zoom, (0.0, -0.03, 0.0))
    rows = []
    for seed in args.seed:
        model = HeadModel(args.n, seed=seed)
        for expr in args.expressions:
            head = model.mesh(None if expr == "neutral" else {expr: 1.0})
            imgs = []
            for view in args.views:
                img = render(head, view, args.size, zoom, focus, args.texture, args.edges)
                Image.fromarray(img).save(os.path.join(args.out, f"{args.prefix}_s{seed}_{expr}_{view}.png"))
                imgs.append(img)
            rows.append(np.concatenate(imgs, axis=1))
    Image.fromarray(np.concatenate(rows, axis=0)).save(os.path.join(args.out, f"{args.prefix}_sheet.png"))
    print(f"wrote {len(rows) * len(args.views)} images to {args.out}")


if __name__ == "__main__":
    main()
