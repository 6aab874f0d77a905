#!/usr/bin/env python
"""Choose the HFDR's loss weights on the validation faces of an ``eval_texture.py`` run.

    python bench/texture_hfdr_choice.py EVAL_DIR [--weights 1,8] [--bands full] [--epochs 20] [--threads 1]

For each micronormal weight (albedo and specular weigh 1) and each HFDR band ("full": the
refiner may change every frequency; "detail": only what is finer than the GDE's texels),
retrains the HFDR of ``EVAL_DIR/model_full`` from a fresh start (its predictor and GDE kept) on ``EVAL_DIR/train`` and
scores GDE-upsampled and GDE + HFDR on ``EVAL_DIR/val`` (masked PSNR, SSIM and detail-band PSNR,
as eval_texture.py).  Prints one JSON line per weight; never reads the test faces.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("eval_dir")
    ap.add_argument("--weights", default="1,8", help="micronormal loss weights to try")
    ap.add_argument("--bands", default="full", help="HFDR bands to try (full, detail)")
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    import torch

    import eval_texture as E
    from geoface.texture.model import TextureModel, TextureTrainConfig, load_sample, reconstruct, train_texture

    torch.set_num_threads(a.threads)
    root = Path(a.eval_dir)
    src = TextureModel.load(root / "model_full")
    val = [load_sample(p) for p in sorted((root / "val").glob("*.npz"))]
    for w, band in ((float(x), b) for x in a.weights.split(",") for b in a.bands.split(",")):
        tag = root / f"hfdr_choice_w{w:g}_{band}_s{a.seed}"
        cfg = TextureTrainConfig(**{**src.cfg.__dict__, "epochs": (0, 0, a.epochs), "hfdr_map_weights": (1.0, w, 1.0),
                                    "seed": a.seed, "nets": dataclasses.replace(src.cfg.nets, hfdr_band=band)})
        m = TextureModel(cfg)  # a fresh HFDR (it starts at its guidance), the trained predictor and GDE
        m.load_state_dict({**m.state_dict(), **{k: v for k, v in src.state_dict().items() if not k.startswith("hfdr.")}})
        m.save(tag.with_name(tag.name + "_init"))
        info = train_texture(root / "train", tag, cfg, quiet=True, init=tag.with_name(tag.name + "_init"))
        model = TextureModel.load(tag)
        row = {"micronormal_weight": w, "band": band, "seed": a.seed, "hfdr_loss": round(info["history"]["hfdr"][-1], 5)}
        for name, refine in (("gde_upsampled", False), ("gde_hfdr", True)):
            rows = [E.metrics(reconstruct(model, d["photo"], refine=refine), d["maps"], d["mask"]) for d in val]
            row[name] = {k: round(float(np.mean([r[k] for r in rows])), 3) for k in rows[0]}
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
