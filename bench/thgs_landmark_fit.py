#!/usr/bin/env python
"""How far the THGS template can open its lips where the images' landmarks say: a per-frame fit.

    python bench/thgs_landmark_fit.py TALK_DIR [--ridge 1e-3] [--iters 200]

For every frame of an ICT talking capture (``geoface talk synth --head ict``), the jaw and mouth
blendshapes the tracker leaves out are fitted, with the tracked pose held, to the frame's 20 mouth
landmarks (least squares in pixels, a small ridge on the weights); then the fitted template's gap
between the inner lips' middles is compared with the person's, in the image (pixels) and in
space (mm), over the training and the held-out frames. It bounds what any model driven through
this template and supervised by 2D landmarks can show of the opening. Prints JSON lines.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    import torch

    from geoface.thgs.model import THGSConfig, THGSModel
    from geoface.thgs.train import train_heldout_split
    from geoface.thgs.data import load_talking, mouth_landmark_targets
    from geoface.thgs.eval import true_lip_gaps_px
    from geoface.thgs.prefit import posed_points

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("talk_dir")
    ap.add_argument("--ridge", type=float, default=1e-3, help="weight of the squared blendshape weights (jaw: x100)")
    ap.add_argument("--iters", type=int, default=200, help="L-BFGS iterations per round (3 rounds)")
    ap.add_argument("--heldout", type=float, default=0.2)
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    d = load_talking(a.talk_dir)
    if "lip_vertices" not in d.meta or "lip_gap_m" not in d.meta or d.landmarks is None:
        raise SystemExit("thgs_landmark_fit: needs an ICT capture (meta.json lip_vertices, lip_gap_m; landmarks.json)")
    m = THGSModel(d.template, THGSConfig(use_saam=False), d.audio.shape[1], len(d))
    m.tracked_joints.copy_(torch.as_tensor(d.tracked_joints))
    m.tracked_expr.copy_(torch.as_tensor(d.tracked_expr))
    verts, px = mouth_landmark_targets(d)
    idx = [int(i[0]) for i in m.gaussians_of(list(verts) + list(d.meta["lip_vertices"]))]
    T, M = len(d), len(verts)
    rot, transl, expr = (torch.as_tensor(x, dtype=torch.float32) for x in (d.rot, d.transl, d.expr))
    uj, ue = ~m.tracked_joints, ~m.tracked_expr
    dr = torch.zeros(T, int(uj.sum()), 3, requires_grad=True)
    de = torch.zeros(T, int(ue.sum()), requires_grad=True)
    P = torch.as_tensor(px, dtype=torch.float32)

    def pose():
        r, e = rot.clone(), expr.clone()
        r[:, uj] = r[:, uj] + dr
        e[:, ue] = e[:, ue] + de
        return posed_points(m, idx, r, transl, e)

    opt = torch.optim.LBFGS([dr, de], max_iter=a.iters, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        uv = d.camera.project(pose()[:, :M].reshape(-1, 3))[0].reshape(T, M, 2)
        loss = ((uv - P) ** 2).sum(-1).mean() + a.ridge * ((de**2).sum(-1).mean() + 100 * (dr**2).sum((-1, -2)).mean())
        loss.backward()
        return loss

    t0 = time.perf_counter()
    for _ in range(3):
        opt.step(closure)
    with torch.no_grad():
        X = pose()
        uv = d.camera.project(X.reshape(-1, 3))[0].reshape(T, -1, 2).numpy()
    rms = float(np.sqrt(((uv[:, :M] - px) ** 2).sum(-1).mean()))
    gap_mm = np.linalg.norm((X[:, M] - X[:, M + 1]).numpy(), axis=-1) * 1000
    gap_px = np.linalg.norm(uv[:, M] - uv[:, M + 1], axis=-1)
    true_mm, true_px = np.asarray(d.meta["lip_gap_m"]) * 1000, true_lip_gaps_px(d)
    print(json.dumps({"bench": "thgs_landmark_fit", "capture": str(a.talk_dir), "frames": T, "ridge": a.ridge,
                      "landmark_rms_px": round(rms, 3), "seconds": round(time.perf_counter() - t0, 1)}))
    tr, te = train_heldout_split(T, a.heldout)
    corr = lambda x, y: round(float(np.corrcoef(x, y)[0, 1]), 4)  # noqa: E731
    for name, f in (("train", tr), ("heldout", te)):
        print(json.dumps({"frames": name, "gap_px_std": round(float(gap_px[f].std()), 3),
                          "gap_px_std_real": round(float(true_px[f].std()), 3), "gap_px_corr_real": corr(gap_px[f], true_px[f]),
                          "gap_mm_std": round(float(gap_mm[f].std()), 3), "gap_mm_std_real": round(float(true_mm[f].std()), 3),
                          "gap_mm_corr_real": corr(gap_mm[f], true_mm[f]),
                          "mm_per_px": round(float(gap_mm[f].std() / gap_px[f].std()), 3),
                          "mm_per_px_real": round(float(true_mm[f].std() / true_px[f].std()), 3)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
