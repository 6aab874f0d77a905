#!/usr/bin/env python
"""Choose the texture model's hash grid on validation faces: one predictor, then the GDE alone
with each hash-encoding variant, scored upsampled (masked PSNR, ``eval_texture.metrics``) on
the validation split of an ``eval_texture.py`` folder.

    python bench/texture_hash_choice.py EVAL_OUT [no_hash hash_1024 hash_128 hash_64_b8 hash_256_t12]

Prints one line per variant (seconds, final training loss, validation PSNRs).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import eval_texture as E  # noqa: E402
from geoface.learn.texture import TextureModel, TextureTrainConfig, load_sample, reconstruct, train_texture  # noqa: E402
from geoface.learn.texture_nets import TextureNetConfig  # noqa: E402

VARIANTS = {"no_hash": dict(use_hash=False), "hash_1024": dict(hash_max_res=1024), "hash_128": dict(hash_max_res=128),
            "hash_64_b8": dict(hash_max_res=64, hash_base_res=8), "hash_256_t12": dict(hash_max_res=256, hash_log2_table=12)}


def main(argv) -> int:
    root, names = Path(argv[0]), argv[1:] or list(VARIANTS)
    torch.set_num_threads(2)
    val = [load_sample(p) for p in sorted((root / "val").glob("*.npz"))]

    def score(md):
        m = TextureModel.load(md)
        rows = [E.metrics(reconstruct(m, d["photo"], refine=False), d["maps"], d["mask"]) for d in val]
        return {k.replace("_psnr", ""): round(float(np.mean([r[k] for r in rows])), 2) for k in rows[0] if "psnr" in k}

    base = dict(gde_res=128, k=2, lr=1e-3, batch=4, hfdr_patches=2, seed=0)
    pred_dir = root / "exp_pred"
    if not (pred_dir / "model.safetensors").exists():
        info = train_texture(root / "train", pred_dir, TextureTrainConfig(nets=TextureNetConfig(use_hash=False),
                                                                          epochs=(30, 0, 0), **base), quiet=True)
        print("predictor", round(info["seconds"]), info["history"]["predictor"][-1], flush=True)
    src = TextureModel.load(pred_dir)
    for name in names:
        cfg = TextureTrainConfig(nets=TextureNetConfig(**VARIANTS[name]), epochs=(0, 30, 0), **base)
        m = TextureModel(cfg)
        m.load_state_dict({**m.state_dict(), **{k: v for k, v in src.state_dict().items() if k.startswith("predictor.")}})
        m.save(root / f"init_{name}")
        info = train_texture(root / "train", root / f"exp_{name}", cfg, quiet=True, init=root / f"init_{name}")
        print(name, round(info["seconds"]), "train gde loss", round(info["history"]["gde"][-1], 4), score(root / f"exp_{name}"),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
