#!/usr/bin/env python
"""Choose the texture model's GDE settings (hash grid, tone mode) on validation faces: one
predictor per model seed, then the GDE alone with each variant, scored upsampled (masked PSNR,
``eval_texture.metrics``) on the held-out splits of an ``eval_texture.py`` folder.

    python bench/texture_hash_choice.py EVAL_OUT [--seeds 0] [--splits val] [--threads 2] [VARIANT ...]

Variants: ``no_hash``, ``hash_1024``, ``hash_128``, ``hash_64_b8``, ``hash_256_t12`` (absolute
tone) and ``rel_hash``, ``rel_no_hash`` (``gde_tone="relative"``, finest grid 128).  Prints one
JSON object per (seed, variant, split) — seconds, final training loss, mean validation PSNRs and
the per-face albedo PSNRs (for paired comparisons) — and appends it to
``EVAL_OUT/gde_choice.jsonl``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import eval_texture as E  # noqa: E402
from geoface.texture.model import TextureModel, TextureTrainConfig, load_sample, reconstruct, train_texture  # noqa: E402
from geoface.texture.nets import TextureNetConfig  # noqa: E402

VARIANTS = {"no_hash": dict(use_hash=False), "hash_1024": dict(hash_max_res=1024), "hash_128": dict(hash_max_res=128),
            "hash_64_b8": dict(hash_max_res=64, hash_base_res=8), "hash_256_t12": dict(hash_max_res=256, hash_log2_table=12),
            "rel_hash": dict(gde_tone="relative"), "rel_no_hash": dict(use_hash=False, gde_tone="relative"),
            "hash_logit": dict(hash_mode="logit")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root")
    ap.add_argument("variants", nargs="*", default=list(VARIANTS), help=", ".join(VARIANTS))
    ap.add_argument("--seeds", default="0", help="model seeds, comma-separated")
    ap.add_argument("--splits", default="val", help="held-out splits to score (val while choosing)")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    if set(a.variants) - set(VARIANTS):
        ap.error(f"unknown variants {sorted(set(a.variants) - set(VARIANTS))}; choose from {', '.join(VARIANTS)}")
    root = Path(a.root)
    torch.set_num_threads(a.threads)
    held = {s: [load_sample(p) for p in sorted((root / s).glob("*.npz"))] for s in a.splits.split(",")}

    def score(md, faces):
        m = TextureModel.load(md)
        rows = [E.metrics(reconstruct(m, d["photo"], refine=False), d["maps"], d["mask"]) for d in faces]
        mean = {k.replace("_psnr", ""): round(float(np.mean([r[k] for r in rows])), 3) for k in rows[0] if "psnr" in k}
        return mean, [r["albedo_psnr"] for r in rows]

    for seed in (int(s) for s in a.seeds.split(",")):
        base = dict(gde_res=128, k=2, lr=1e-3, batch=4, hfdr_patches=2, seed=seed)
        pred_dir = root / f"exp_pred_s{seed}"
        if not (pred_dir / "model.safetensors").exists():
            info = train_texture(root / "train", pred_dir, TextureTrainConfig(nets=TextureNetConfig(use_hash=False),
                                                                              epochs=(30, 0, 0), **base), quiet=True)
            print(json.dumps({"seed": seed, "stage": "predictor", "seconds": round(info["seconds"]),
                              "loss": round(info["history"]["predictor"][-1], 5)}), flush=True)
        src = TextureModel.load(pred_dir)
        for name in a.variants:
            cfg = TextureTrainConfig(nets=TextureNetConfig(**VARIANTS[name]), epochs=(0, 30, 0), **base)
            out_dir = root / f"exp_{name}_s{seed}"
            info = None
            if not (out_dir / "model.safetensors").exists():
                torch.manual_seed(seed)
                m = TextureModel(cfg)
                m.load_state_dict({**m.state_dict(), **{k: v for k, v in src.state_dict().items() if k.startswith("predictor.")}})
                m.save(root / f"init_{name}_s{seed}")
                info = train_texture(root / "train", out_dir, cfg, quiet=True, init=root / f"init_{name}_s{seed}")
            for split, faces in held.items():
                mean, per_face = score(out_dir, faces)
                row = {"seed": seed, "variant": name, "split": split, "faces": len(faces), **mean, "albedo_per_face": per_face}
                if info is not None:
                    row.update(seconds=round(info["seconds"]), gde_loss=round(info["history"]["gde"][-1], 5))
                print(json.dumps(row), flush=True)
                with open(root / "gde_choice.jsonl", "a") as f:
                    f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
