"""Time the Gaussian rasterizer: forward and backward, 10K/100K Gaussians at 256²/512².

One JSON line per (device, backend, Gaussians, resolution): median forward and backward
wall seconds over ``--repeats`` runs after one warm-up (on CPU also the process CPU seconds,
all threads, which a busy shared machine disturbs less), the torch thread count, and the
mean alpha of the image (how much of it the head covers).

Scene: Gaussians on the surface of a head-sized ellipsoid (semi-axes 0.09 × 0.12 × 0.10 m,
as the procedural head), scales sqrt(area / (π N)) × U(0.5, 1.5) per axis (what a fitted
head has: neighbours overlap about once), random rotations, opacities sigmoid(N(1, 1)), RGB
colours; camera 0.45 m in front, 40° vertical field of view (the head fills ~70% of the
height). Loss for backward: Σ w·rgb + Σ alpha with a fixed random image w.

    python bench/bench_splat.py                       # CPU, torch path
    python bench/bench_splat.py --device cuda         # torch path on CUDA + gsplat if importable
    python bench/bench_splat.py --quick               # smoke: 2K Gaussians at 64², 1 repeat
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

AXES = (0.09, 0.12, 0.10)  # ellipsoid semi-axes, metres


def head_scene(n: int, device, seed: int = 0):
    """Random Gaussians on a head-sized ellipsoid; returns the parameter tensors (leaves)."""
    import numpy as np
    import torch

    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b, c = AXES
    area = 4 * np.pi * ((a * b) ** 1.6 + (a * c) ** 1.6 + (b * c) ** 1.6) ** (1 / 1.6) / 3 ** (1 / 1.6)
    s = np.sqrt(area / (np.pi * n))
    arrays = (d * np.array(AXES), np.log(rng.uniform(0.5, 1.5, (n, 3)) * s), rng.normal(size=(n, 4)),
              rng.normal(1.0, 1.0, n), rng.uniform(size=(n, 3)))
    return [torch.tensor(x, dtype=torch.float32, device=device).requires_grad_(True) for x in arrays], float(s)


def _sync(device):
    import torch
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_case(n, res, device, backend, repeats):
    import torch
    from geoface.splat import GaussianTensors, look_at, rasterize

    params, s = head_scene(n, device)
    cam = look_at([0, 0, 0.45], [0, 0, 0], width=res, height=res, fov_y_deg=40)
    w = torch.rand(res, res, 3, generator=torch.Generator().manual_seed(0)).to(device)
    fwd, bwd, cfwd, cbwd, alpha_mean = [], [], [], [], 0.0
    for r in range(repeats + 1):  # the first run warms up (allocator, kernels) and is dropped
        for p in params:
            p.grad = None
        _sync(device)
        c0, t0 = time.process_time(), time.perf_counter()
        rgb, alpha, depth = rasterize(GaussianTensors(*params), cam, background=(1.0, 1.0, 1.0),
                                      backend=backend)
        _sync(device)
        c1, t1 = time.process_time(), time.perf_counter()
        ((rgb * w).sum() + alpha.sum()).backward()
        _sync(device)
        c2, t2 = time.process_time(), time.perf_counter()
        if r:
            fwd.append(t1 - t0)
            bwd.append(t2 - t1)
            cfwd.append(c1 - c0)
            cbwd.append(c2 - c1)
        alpha_mean = float(alpha.detach().mean())
    med = lambda xs: round(statistics.median(xs), 4)  # noqa: E731
    row = {"forward_s": med(fwd), "backward_s": med(bwd), "forward_all": [round(x, 4) for x in fwd],
           "alpha_mean": round(alpha_mean, 3), "scale_m": round(s, 5)}
    if device.type == "cpu":  # process CPU time (all threads): steadier than wall time on a shared machine
        row.update(forward_cpu_s=med(cfwd), backward_cpu_s=med(cbwd))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="cpu or cuda[:k]")
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--res", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (CPU)")
    ap.add_argument("--backends", nargs="+", default=None,
                    help="torch and/or gsplat (default: torch, plus gsplat on CUDA when importable)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 2K Gaussians at 64², 1 repeat")
    args = ap.parse_args()
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    if args.quick:
        args.sizes, args.res, args.repeats = [2000], [64], 1
    device = torch.device(args.device)
    backends = args.backends
    if backends is None:
        backends = ["torch"]
        if device.type == "cuda":
            try:
                import gsplat  # noqa: F401
                backends.append("gsplat")
            except ImportError:
                print(json.dumps({"note": "gsplat not importable; torch path only"}), flush=True)
    info = {"device": str(device), "threads": torch.get_num_threads(), "torch": torch.__version__}
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    for n in args.sizes:
        for res in args.res:
            for backend in backends:
                row = {"name": "splat_rasterize", "gaussians": n, "res": res, "backend": backend,
                       "repeats": args.repeats, **info}
                try:
                    row.update(time_case(n, res, device, backend, args.repeats))
                except Exception as e:  # report and go on with the other cases
                    row["error"] = f"{type(e).__name__}: {e}"[:300]
                print(json.dumps(row), flush=True)
                if device.type == "cuda":
                    torch.cuda.empty_cache()


if __name__ == "__main__":
    main()
