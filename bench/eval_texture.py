#!/usr/bin/env python
"""Evaluate the 4K-texture model (predictor → GDE → HFDR) on held-out synthetic faces.

    python bench/eval_texture.py [--train 24] [--test 4] [--res 1024] [--k 4] [--gde-res 256]
                                 [--epochs 20,20,20] [--device cpu|cuda] [--out DIR] [--quick]

1. writes procedural training and held-out samples (``geoface texture synth``'s generator;
   different seeds), or reuses them in ``--out``;
2. trains the full model and the ablation without the UV hash encoding (same seed and sizes);
3. on the held-out photos, PSNR and SSIM of albedo, micronormal and specular (inside the face
   mask), and the PSNR of their detail band (image minus a σ = 4 px blur, away from the mask
   border) for: GDE upsampled (the super-resolution-style baseline), GDE + HFDR, and
   GDE + HFDR without hash encoding;
4. peak memory and time of inference at ``--sizes`` (default 1024, 2048, 4096), each in a
   fresh process (peak RSS during inference, VmHWM reset after loading the model, and the RSS
   before it), CPU.

Prints one JSON object per line; ``--out/results.json`` collects them.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from geoface.errors import GeofaceError  # noqa: E402

MAPS = {"albedo": slice(0, 3), "micronormal": slice(3, 6), "specular": slice(6, 7)}


def emit(rows, **row):
    print(json.dumps(row), flush=True)
    rows.append(row)


def metrics(pred: dict, gt: np.ndarray, mask: np.ndarray) -> dict:
    """PSNR (dB) and SSIM per map inside the mask's bounding box (outside-mask pixels zeroed)."""
    from scipy.ndimage import binary_erosion, gaussian_filter
    from skimage.metrics import structural_similarity
    ys, xs = np.nonzero(mask)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    m = mask[box][..., None]
    out = {}
    for name, s in MAPS.items():
        p = pred[name][box] * m
        g = gt[box][..., s] * m
        mse = float(((p - g) ** 2)[np.broadcast_to(m, p.shape)].mean())
        out[f"{name}_psnr"] = round(10 * np.log10(1.0 / max(mse, 1e-12)), 3)
        out[f"{name}_ssim"] = round(float(structural_similarity(g, p, data_range=1.0, channel_axis=2,
                                                                gaussian_weights=True, sigma=1.5)), 4)
        # detail band: the image minus its Gaussian blur (σ = 4 px) — what upsampling cannot add
        hp = lambda x: x - gaussian_filter(x, (4, 4, 0))  # noqa: E731
        inner = np.broadcast_to(binary_erosion(m[..., 0], iterations=12)[..., None], p.shape)
        mse_hf = float(((hp(p) - hp(g)) ** 2)[inner].mean()) if inner.any() else float("nan")
        out[f"{name}_detail_psnr"] = round(10 * np.log10(1.0 / max(mse_hf, 1e-12)), 3)
    return out


def _status_mib(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024  # kB -> MiB
    raise KeyError(key)


def _reset_peak_rss() -> float:
    """Current RSS (MiB), after resetting the kernel's peak-RSS mark to it where Linux allows.

    ``ru_maxrss`` cannot be used here: Linux keeps it across fork + exec, so a child started by
    a big parent reports the parent's peak. Writing 5 to /proc/self/clear_refs resets VmHWM."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return _status_mib("VmRSS")
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _peak_rss() -> float:
    try:
        return _status_mib("VmHWM")
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def infer_child(model_dir: str, size: int, photo_path: str, k: int) -> None:
    """Run in a fresh process: reconstruct one photo resized to size², report time and peak RSS."""
    import cv2
    import torch

    from geoface.learn.texture import TextureModel, load_sample, reconstruct
    torch.set_num_threads(int(os.environ.get("EVAL_THREADS", "2")))
    model = TextureModel.load(model_dir)
    photo = load_sample(photo_path)["photo"]
    photo = cv2.resize(photo, (size, size), interpolation=cv2.INTER_LINEAR if size > photo.shape[0] else cv2.INTER_AREA)
    base = _reset_peak_rss()
    t = time.perf_counter()
    out = reconstruct(model, photo, k=k * size // 1024 if size >= 1024 else k)
    dt = time.perf_counter() - t
    peak = _peak_rss()
    arrays = (photo.nbytes + sum(v.nbytes for v in out.values())) / 2**20
    print(json.dumps({"size": size, "seconds": round(dt, 2), "peak_rss_mib": round(peak, 1),
                      "rss_before_mib": round(base, 1), "io_arrays_mib": round(arrays, 1),
                      "patches_per_side": k * size // 1024 if size >= 1024 else k}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", type=int, default=24)
    ap.add_argument("--test", type=int, default=4)
    ap.add_argument("--res", type=int, default=1024)
    ap.add_argument("--k", type=int, default=4)
    ap.add_argument("--gde-res", type=int, default=256)
    ap.add_argument("--epochs", default="20,20,20")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--workers", type=int, default=1, help="processes writing the synthetic samples")
    ap.add_argument("--sizes", default="1024,2048,4096", help="inference sizes for time/memory ('' = skip)")
    ap.add_argument("--out", default="/tmp/geoface_eval_texture")
    ap.add_argument("--quick", action="store_true", help="tiny smoke configuration (about a minute)")
    ap.add_argument("--_infer", nargs=4, metavar=("MODEL", "SIZE", "PHOTO", "K"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a._infer:
        infer_child(a._infer[0], int(a._infer[1]), a._infer[2], int(a._infer[3]))
        return 0
    import torch

    from geoface.learn.skin_synth import make_texture_dataset
    from geoface.learn.texture import TextureModel, TextureTrainConfig, load_sample, reconstruct, train_texture
    from geoface.learn.texture_nets import TextureNetConfig
    if a.quick:
        a.train, a.test, a.res, a.k, a.gde_res, a.epochs, a.sizes = 4, 2, 128, 2, 64, "3,3,3", "256"
    if a.threads:
        torch.set_num_threads(a.threads)
    epochs = tuple(int(e) for e in a.epochs.split(","))
    out = Path(a.out)
    rows: list = []
    emit(rows, bench="eval_texture", stage="config", train=a.train, test=a.test, res=a.res, k=a.k,
         gde_res=a.gde_res, epochs=list(epochs), device=a.device, threads=torch.get_num_threads())
    t = time.perf_counter()
    make_texture_dataset(out / "train", a.train, a.res, seed=1, workers=a.workers, quiet=True)
    test = make_texture_dataset(out / "test", a.test, a.res, seed=2, workers=a.workers, quiet=True)
    emit(rows, stage="data", seconds=round(time.perf_counter() - t, 1))
    models = {}
    for name, use_hash in (("full", True), ("no_hash", False)):
        cfg = TextureTrainConfig(nets=TextureNetConfig(use_hash=use_hash), gde_res=a.gde_res, k=a.k,
                                 epochs=epochs, lr=a.lr, batch=a.batch, seed=0)
        info = train_texture(out / "train", out / f"model_{name}", cfg, quiet=True, device=a.device)
        models[name] = TextureModel.load(out / f"model_{name}")
        emit(rows, stage="train", model=name, seconds=round(info["seconds"], 1),
             final={k: round(v[-1], 5) for k, v in info["history"].items() if v},
             first={k: round(v[0], 5) for k, v in info["history"].items() if v})
    variants = {"gde_upsampled": ("full", False), "gde_hfdr": ("full", True), "gde_hfdr_no_hash": ("no_hash", True)}
    for vname, (mname, refine) in variants.items():
        per = []
        for p in test:
            d = load_sample(p)
            pred = reconstruct(models[mname], d["photo"], refine=refine, device=a.device)
            per.append(metrics(pred, d["maps"], d["mask"]))
        mean = {k: round(float(np.mean([r[k] for r in per])), 4) for k in per[0]}
        emit(rows, stage="heldout", variant=vname, n=len(per), **mean)
    for size in [int(s) for s in a.sizes.split(",") if s]:
        env = dict(os.environ, EVAL_THREADS=str(a.threads or torch.get_num_threads()))
        r = subprocess.run([sys.executable, __file__, "--_infer", str(out / "model_full"), str(size),
                            str(test[0]), str(a.k)], capture_output=True, text=True, env=env)
        if r.returncode:
            emit(rows, stage="inference", size=size, error=r.stderr.strip().splitlines()[-1:])
        else:
            emit(rows, stage="inference", device="cpu", **json.loads(r.stdout.strip().splitlines()[-1]))
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except GeofaceError as e:
        print(f"eval_texture: error: {e}", file=sys.stderr)
        sys.exit(2)
