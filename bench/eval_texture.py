#!/usr/bin/env python
"""Evaluate the 4K-texture model (predictor → GDE → HFDR) on held-out synthetic faces.

    python bench/eval_texture.py [--heads ict|procedural] [--train 64] [--val 8] [--test 8]
                                 [--res 512] [--k 2] [--gde-res 128] [--epochs 30,30,30]
                                 [--hfdr-patches 4] [--size4k 4096] [--device cpu|cuda] [--out DIR] [--quick]

1. writes training, validation and test samples (``geoface texture synth``'s generator; seeds
   1, 3 and 2, so every face — an ICT-FaceKit identity drawn at random, its expression, skin,
   lights and camera — is new to the model), or reuses them in ``--out``;
2. trains the full model and the ablation without the UV hash encoding (same seed and sizes);
3. on the validation and the test faces, inside the face mask only: PSNR, SSIM (the SSIM map
   averaged over mask pixels at least 5 px from its border, so no window sees the background)
   and the PSNR of the detail band (image minus a σ = 4 px blur, mask eroded by 12 px) of
   albedo, micronormal and specular, for
   * ``constant``: the training set's mean maps (flat micronormal), whatever the photo;
   * ``photo``: the photo itself as albedo, linearised (γ 2.2) with a per-channel gain fitted
     on the training faces (the input projected to UV, seen in image space); albedo only;
   * ``gde_upsampled``: the GDE's maps bilinearly upsampled (the super-resolution baseline);
     ``gde_upsampled_no_hash``: the same from the GDE trained without hash encoding;
   * ``gde_hfdr``: GDE + HFDR (the model); ``gde_hfdr_no_hash``: the same without hash encoding.
   Rows per face carry ``face``; the summary rows per split carry the mean and, against each
   baseline, the number of faces the model beats;
4. with ``--size4k S``: a new ICT face rendered at S² with its 68 landmarks, and
   ``geoface texture reconstruct PHOTO --landmarks L.json`` run on it in a fresh process under
   ``/usr/bin/time``: wall time, peak RSS, the sizes of the maps written, and their masked
   metrics against that face's true maps beside the constant's.

Prints one JSON object per line; ``--out/results.jsonl`` collects them.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from geoface.errors import GeofaceError  # noqa: E402

MAPS = {"albedo": slice(0, 3), "micronormal": slice(3, 6), "specular": slice(6, 7)}
SEEDS = {"train": 1, "test": 2, "val": 3, "4k": 4}


def emit(out: Path, **row):
    print(json.dumps(row), flush=True)
    with open(out / "results.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")


def metrics(pred: dict, gt: np.ndarray, mask: np.ndarray) -> dict:
    """Masked PSNR (dB), masked SSIM and masked detail-band PSNR per map (see the module)."""
    from scipy.ndimage import binary_erosion, gaussian_filter
    from skimage.metrics import structural_similarity
    ys, xs = np.nonzero(mask)
    pad = 16
    box = (slice(max(ys.min() - pad, 0), ys.max() + pad + 1), slice(max(xs.min() - pad, 0), xs.max() + pad + 1))
    m = mask[box]
    inner_ssim = binary_erosion(m, iterations=5)
    inner_hf = binary_erosion(m, iterations=12)
    out = {}
    for name, s in MAPS.items():
        p = np.where(m[..., None], pred[name][box], 0.0).astype(np.float64)
        g = np.where(m[..., None], gt[box][..., s], 0.0).astype(np.float64)
        mse = float(((p - g) ** 2)[m].mean())
        out[f"{name}_psnr"] = round(10 * np.log10(1.0 / max(mse, 1e-12)), 3)
        _, smap = structural_similarity(g, p, data_range=1.0, channel_axis=2, gaussian_weights=True,
                                        sigma=1.5, use_sample_covariance=False, full=True)
        out[f"{name}_ssim"] = round(float(smap[inner_ssim].mean()), 4)
        hp = lambda x: x - gaussian_filter(x, (4, 4, 0))  # noqa: E731
        mse_hf = float(((hp(p) - hp(g)) ** 2)[inner_hf].mean())
        out[f"{name}_detail_psnr"] = round(10 * np.log10(1.0 / max(mse_hf, 1e-12)), 3)
    return out


def fit_baselines(files) -> dict:
    """The constant's mean maps and the photo baseline's per-channel gain, from training faces."""
    from geoface.texture.model import load_sample
    s_map, n, num, den = np.zeros(7), 0, np.zeros(3), np.zeros(3)
    for f in files:
        d = load_sample(f, ("photo", "maps"))
        m = d["mask"]
        s_map += d["maps"][m].sum(0)
        n += int(m.sum())
        lin = d["photo"][m].astype(np.float64) ** 2.2
        num += (lin * d["maps"][m][:, :3]).sum(0)
        den += (lin * lin).sum(0)
    mean = s_map / n
    mean[3:6] = [0.5, 0.5, 1.0]  # a flat micronormal (the mean of unit normals is not unit)
    return {"mean": mean, "gain": num / den}


def baseline_maps(kind: str, photo: np.ndarray, fitted: dict) -> dict:
    H, W = photo.shape[:2]
    const = {k: np.broadcast_to(fitted["mean"][s].astype(np.float32), (H, W, s.stop - s.start)) for k, s in MAPS.items()}
    if kind == "constant":
        return const
    return {**const, "albedo": np.clip(photo.astype(np.float64) ** 2.2 * fitted["gain"], 0, 1)}


def summarise(out: Path, split: str, per: dict) -> None:
    """Mean per variant, and how many faces the model beats each baseline on."""
    keys = list(next(iter(per.values()))[0])
    for v, rows in per.items():
        row = {k: round(float(np.mean([r[k] for r in rows])), 3) for k in keys}
        if v != "gde_hfdr":
            for k in keys:
                if k.endswith("psnr"):
                    row[f"wins_{k}"] = int(sum(a[k] > b[k] for a, b in zip(per["gde_hfdr"], rows)))
        emit(out, stage="heldout", split=split, variant=v, n=len(rows), **row)


def read_png16(path) -> np.ndarray:
    """A 16-bit PNG the CLI wrote → float [H, W, C] in [0, 1], RGB order."""
    import cv2
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    img = img[..., None] if img.ndim == 2 else img[..., ::-1]
    return img.astype(np.float32) / 65535.0


def run_4k(a, out: Path, model_dir: Path, fitted: dict) -> None:
    """Render one new face at ``a.size4k``², write its photo and landmarks, run the CLI on them."""
    from geoface.texture.synth import make_texture_dataset
    from geoface.texture.model import load_sample
    from geoface.images import save_image
    size = a.size4k
    t = time.perf_counter()
    [path] = make_texture_dataset(out / f"face{size}", 1, size, map_res=size, seed=SEEDS["4k"], head_source="ict",
                                  quiet=True, supersample=1)  # 2× of 4K would need ~30 GB
    d = load_sample(path)
    with np.load(path) as z:
        lm = z["landmarks"]
    photo_png, lm_json = out / f"face{size}" / "photo.png", out / f"face{size}" / "landmarks.json"
    save_image(photo_png, d["photo"], bits=16)
    lm_json.write_text(json.dumps({"image_size": [size, size], "landmarks": lm.tolist()}))
    emit(out, stage="4k_data", size=size, seconds=round(time.perf_counter() - t, 1))
    maps_dir = out / f"maps{size}"
    if maps_dir.exists():
        import shutil
        shutil.rmtree(maps_dir)
    k = a.k * size // a.res
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "geoface", "texture", "reconstruct", str(photo_png),
           "--model", str(model_dir), "--landmarks", str(lm_json), "--k", str(k), "--uv-size", str(size), "-o", str(maps_dir)]
    env = dict(os.environ, OMP_NUM_THREADS=str(a.threads or 2))
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode:
        emit(out, stage="4k_reconstruct", size=size, error=r.stderr.strip().splitlines()[-3:])
        return
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", r.stderr).group(1)
    secs = sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall.split(":"))))
    pred = {f.stem: read_png16(f) for f in sorted(maps_dir.glob("*.png"))}
    shapes = {k: list(v.shape) for k, v in pred.items()}
    pred = {k: pred[k][..., : s.stop - s.start] for k, s in MAPS.items()}
    emit(out, stage="4k_reconstruct", size=size, seconds=round(secs, 1), peak_rss_mib=round(peak_kb / 1024, 1),
         patches_per_side=k, message=r.stdout.strip(), written=shapes, threads=int(env["OMP_NUM_THREADS"]))
    emit(out, stage="4k_heldout", size=size, variant="gde_hfdr", **metrics(pred, d["maps"], d["mask"]))
    emit(out, stage="4k_heldout", size=size, variant="constant",
         **metrics(baseline_maps("constant", d["photo"], fitted), d["maps"], d["mask"]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--heads", choices=("ict", "procedural"), default="ict")
    ap.add_argument("--train", type=int, default=64)
    ap.add_argument("--val", type=int, default=8)
    ap.add_argument("--test", type=int, default=8)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--gde-res", type=int, default=128)
    ap.add_argument("--epochs", default="30,30,30")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--hfdr-patches", type=int, default=4, help="random HFDR patches per face and step")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--workers", type=int, default=1, help="processes writing the synthetic samples")
    ap.add_argument("--supersample", type=int, default=2, help="rendered pixels averaged per photo pixel, per side")
    ap.add_argument("--map-weights", default="1,1,1", help="GDE loss weights of albedo, micronormal, specular")
    ap.add_argument("--hfdr-map-weights", default=None, help="HFDR loss weights (default the model's)")
    ap.add_argument("--seed", type=int, default=0, help="model seed (initialisation, batches); the data stay the same")
    ap.add_argument("--no-ablation", action="store_true",
                    help="train and score only the model with hash encoding (compare it with the no-hash model of an "
                         "earlier run of the same data and seed: texture_seeds.py OLD.jsonl+NEW.jsonl)")
    ap.add_argument("--hash-mode", choices=("input", "logit"), default=None,
                    help="where the GDE's hash features go (default the model's)")
    ap.add_argument("--gde-tone", choices=("absolute", "relative"), default=None,
                    help="how the GDE reads skin tone (default the model's)")
    ap.add_argument("--hfdr-band", choices=("full", "detail"), default=None,
                    help="what the HFDR refines (default the model's)")
    ap.add_argument("--hash-max-res", type=int, default=None, help="finest hash-grid resolution (default the model's)")
    ap.add_argument("--hash-log2-table", type=int, default=None, help="log2 of the hash table size (default the model's)")
    ap.add_argument("--size4k", type=int, default=4096, help="size of the reconstruct-from-landmarks run (0 = skip)")
    ap.add_argument("--out", default="/tmp/geoface_eval_texture")
    ap.add_argument("--splits", default="val,test", help="the held-out splits to score (val while choosing settings)")
    ap.add_argument("--quick", action="store_true", help="tiny smoke configuration (a few minutes)")
    a = ap.parse_args(argv)
    import torch

    from geoface.texture.synth import make_texture_dataset
    from geoface.texture.model import TextureModel, TextureTrainConfig, load_sample, reconstruct, train_texture
    from geoface.texture.nets import TextureNetConfig
    if a.quick:
        a.train, a.val, a.test, a.res, a.k, a.gde_res, a.epochs, a.size4k = 4, 2, 2, 128, 2, 64, "3,3,3", 512
    if a.threads:
        torch.set_num_threads(a.threads)
    epochs = tuple(int(e) for e in a.epochs.split(","))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    emit(out, bench="eval_texture", stage="config", heads=a.heads, train=a.train, val=a.val, test=a.test, res=a.res,
         k=a.k, gde_res=a.gde_res, epochs=list(epochs), hfdr_patches=a.hfdr_patches, supersample=a.supersample,
         map_weights=a.map_weights, hfdr_map_weights=a.hfdr_map_weights, seed=a.seed, hash_max_res=a.hash_max_res, hash_log2_table=a.hash_log2_table, hfdr_band=a.hfdr_band, gde_tone=a.gde_tone, hash_mode=a.hash_mode, no_ablation=a.no_ablation,
         device=a.device, threads=torch.get_num_threads())
    t = time.perf_counter()
    files = {split: make_texture_dataset(out / split, n, a.res, seed=SEEDS[split], workers=a.workers, quiet=True,
                                         head_source=a.heads, supersample=a.supersample)
             for split, n in (("train", a.train), ("val", a.val), ("test", a.test))}
    emit(out, stage="data", seconds=round(time.perf_counter() - t, 1))
    fitted = fit_baselines(files["train"])
    models = {}
    for name, use_hash in (("full", True), ("no_hash", False))[: 1 if a.no_ablation else 2]:
        mdir = out / f"model_{name}"
        if not (mdir / "model.safetensors").exists():
            hash_opts = {k: v for k, v in (("hash_max_res", a.hash_max_res), ("hash_log2_table", a.hash_log2_table),
                                           ("hfdr_band", a.hfdr_band), ("gde_tone", a.gde_tone), ("hash_mode", a.hash_mode)) if v}
            nets = TextureNetConfig(use_hash=use_hash, **hash_opts)
            hw = {"hfdr_map_weights": tuple(float(w) for w in a.hfdr_map_weights.split(","))} if a.hfdr_map_weights else {}
            cfg = TextureTrainConfig(nets=nets, gde_res=a.gde_res, k=a.k,
                                     map_weights=tuple(float(w) for w in a.map_weights.split(",")),
                                     epochs=epochs, lr=a.lr, batch=a.batch,
                                     hfdr_patches=a.hfdr_patches, seed=a.seed, **hw)
            info = train_texture(out / "train", mdir, cfg, quiet=True, device=a.device)
            emit(out, stage="train", model=name, seconds=round(info["seconds"], 1),
                 final={k: round(v[-1], 5) for k, v in info["history"].items() if v},
                 first={k: round(v[0], 5) for k, v in info["history"].items() if v})
        models[name] = TextureModel.load(mdir)
    variants = {"constant": None, "photo": None, "gde_upsampled": ("full", False),
                "gde_upsampled_no_hash": ("no_hash", False), "gde_hfdr": ("full", True),
                "gde_hfdr_no_hash": ("no_hash", True)}
    variants = {k: v for k, v in variants.items() if v is None or v[0] in models}
    for split in a.splits.split(","):
        per: dict = {v: [] for v in variants}
        for i, p in enumerate(files[split]):
            d = load_sample(p)
            for v, spec in variants.items():
                pred = (baseline_maps(v, d["photo"], fitted) if spec is None else
                        reconstruct(models[spec[0]], d["photo"], refine=spec[1], device=a.device))
                per[v].append(metrics(pred, d["maps"], d["mask"]))
                emit(out, stage="face", split=split, face=i, variant=v, **per[v][-1])
        summarise(out, split, per)
    if a.size4k:
        run_4k(a, out, out / "model_full", fitted)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except GeofaceError as e:
        print(f"eval_texture: error: {e}", file=sys.stderr)
        sys.exit(2)
