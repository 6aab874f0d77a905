"""The DDPM's data path at scale, and its speed per step; JSON lines.

``memory``: a dataset of ``--items`` geometry-image folders at ``--res`` (synthetic files of the
real size: ``--distinct`` different items, the others hard links to their files, so every
folder is read and decoded on its own) and a training run over it in a fresh process; prints
that process's peak resident memory, against what preloading every item as float32 (the
loader before it was lazy) would hold.

``speed``: seconds per training step of the ``small`` model (batch ``--batch``) at each of
``--resolutions`` on this machine (``--threads`` CPU threads), the floating-point work per step
(torch's FLOP counter) and the operations it dispatches; a GPU's time per step is estimated
as the larger of the work at an assumed sustained rate (``--gpu-tflops``) and the operations
at an assumed launch cost (``--launch-us``): an estimate, not a measurement.

    python bench/bench_ddpm_data.py memory --items 10000 --res 128
    python bench/bench_ddpm_data.py speed --resolutions 64 128 256 --threads 2
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402


def emit(**d):
    print(json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in d.items()}), flush=True)


def make_items(root: Path, items: int, distinct: int, res: int, seed: int = 0) -> Path:
    """``items`` item folders + manifest; positions a bumpy sphere patch per distinct item."""
    from geoface.gimage import GeometryImage, save_gimage

    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, res), np.linspace(0, 1, res))
    base = []
    for k in range(distinct):
        th, ph = np.pi * (0.1 + 0.8 * v), 2 * np.pi * (0.1 + 0.8 * u)
        r = 1 + 0.05 * np.sin(rng.uniform(2, 9) * u + k) * np.cos(rng.uniform(2, 9) * v)
        P = np.stack([r * np.sin(th) * np.cos(ph), r * np.cos(th), r * np.sin(th) * np.sin(ph)])
        N = P / np.linalg.norm(P, axis=0)
        img = np.concatenate([(P + 1.1) / 2.2, (N + 1) / 2]).astype(np.float32)
        meta = {"bbox_min": [-1.1, -1.1, -1.1], "bbox_max": [1.1, 1.1, 1.1], "channels": ["px", "py", "pz", "nx", "ny", "nz"],
                "resolution": res, "version": 2, "align_corners": True}
        folder = root / f"item_{k:05d}" / "aug0"
        save_gimage(folder, GeometryImage(img, np.ones((res, res), bool), meta))
        base.append(folder)
    rows = []
    for k in range(items):
        folder = root / f"item_{k:05d}" / "aug0"
        if k >= distinct:
            folder.mkdir(parents=True)
            for f in base[k % distinct].iterdir():
                os.link(f, folder / f.name)
        rows.append({"item": f"item_{k:05d}/aug0", "status": "ok", "prompt": f"a head number {k % 97}",
                     "bbox": {"min": [-1.1, -1.1, -1.1], "max": [1.1, 1.1, 1.1]}})
    (root / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root


_CHILD = """
import json, resource, sys, time, torch
torch.set_num_threads({threads})
from geoface.ddpm.model import DDPMConfig, train
cfg = DDPMConfig.preset("small", res={res}, steps={steps}, batch_size={batch}, text_encoder="hash:384",
                        checkpoint_every=10**9, augment=True)
t = time.perf_counter()
last = train({data!r}, {run!r}, cfg, quiet=True, cache_mb={cache_mb}, gradient_checkpointing={gc})
print(json.dumps({{"seconds": time.perf_counter() - t, "steps": last["step"], "steps_per_second": last["steps_per_second"],
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}}))
"""


def memory(a) -> None:
    with tempfile.TemporaryDirectory(prefix="bench_ddpm_data_") as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        data = make_items(root / "data", a.items, a.distinct, a.res)
        on_disk = sum(f.stat().st_size for f in (data / "item_00000" / "aug0").iterdir())
        emit(case="dataset", items=a.items, res=a.res, distinct=a.distinct, seconds=time.perf_counter() - t,
             bytes_per_item=on_disk)
        code = _CHILD.format(threads=a.threads, res=a.res, steps=a.steps, batch=a.batch, data=str(data),
                             run=str(root / "run"), cache_mb=a.cache_mb, gc=bool(a.gradient_checkpointing))
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
        if out.returncode:
            raise SystemExit(out.stderr[-2000:])
        r = json.loads(out.stdout.strip().splitlines()[-1])
        preload_gb = a.items * 6 * a.res * a.res * 4 / 2**30
        emit(case="memory", items=a.items, res=a.res, batch=a.batch, steps=r["steps"], cache_mb=a.cache_mb,
             peak_rss_mb=r["peak_rss_mb"], preload_float32_gb=preload_gb, steps_per_second=r["steps_per_second"],
             threads=a.threads, gradient_checkpointing=bool(a.gradient_checkpointing))


class _OpCounter:
    """Counts the aten operations a step dispatches (each is at least one GPU kernel launch)."""

    def __enter__(self):
        from torch.utils._python_dispatch import TorchDispatchMode

        counter = self

        class Mode(TorchDispatchMode):
            def __torch_dispatch__(self, func, types, args=(), kwargs=None):
                counter.n += 1
                return func(*args, **(kwargs or {}))

        self.n = 0
        self._mode = Mode()
        self._mode.__enter__()
        return self

    def __exit__(self, *exc):
        self._mode.__exit__(*exc)
        return False


def speed(a) -> None:
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from geoface.ddpm.model import DDPMConfig, build_scheduler, build_unet, ddpm_loss

    torch.set_num_threads(a.threads)
    dev = torch.device(a.device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    for res, patch in [(r, p) for r in a.resolutions for p in a.patch]:
        cfg = DDPMConfig.preset("small", res=res, cross_attention_dim=384, channels=6, modalities=("position", "normal"),
                                patch=patch)
        torch.manual_seed(0)
        unet = build_unet(cfg).to(dev)
        opt = torch.optim.AdamW(unet.parameters(), lr=1e-4)
        sched = build_scheduler(cfg)
        g = torch.Generator().manual_seed(0)
        x0 = torch.randn(a.batch, cfg.channels, res, res, generator=g).to(dev)
        cond = torch.randn(a.batch, 32, 384, generator=g).to(dev)

        def step():
            eps = torch.randn(x0.shape, generator=g).to(dev)
            t = torch.randint(0, 1000, (a.batch,), generator=g).to(dev)
            loss, _ = ddpm_loss(unet(sched.add_noise(x0, eps, t), t, encoder_hidden_states=cond).sample, eps, cfg.modalities)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        with FlopCounterMode(display=False) as fc, _OpCounter() as ops:
            step()
        flops = fc.get_total_flops()
        times = []
        for _ in range(a.repeats):
            sync()
            t = time.perf_counter()
            step()
            sync()
            times.append(time.perf_counter() - t)
        sec = float(np.median(times))
        extra = {"gpu": torch.cuda.get_device_name(dev)} if dev.type == "cuda" else {"threads": a.threads}
        emit(case="speed", res=res, patch=patch, batch=a.batch, device=dev.type, **extra, params=sum(p.numel() for p in unet.parameters()),
             seconds_per_step=sec, steps_per_second=1 / sec, gflop_per_step=flops / 1e9,
             ops_per_step=ops.n, gpu_estimate_steps_per_second=1.0 / max(flops / (a.gpu_tflops * 1e12), ops.n * a.launch_us * 1e-6),
             gpu_tflops_assumed=a.gpu_tflops, gpu_launch_us_assumed=a.launch_us)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    m = sub.add_parser("memory")
    m.add_argument("--items", type=int, default=10000)
    m.add_argument("--distinct", type=int, default=64)
    m.add_argument("--res", type=int, default=128)
    m.add_argument("--steps", type=int, default=40)
    m.add_argument("--batch", type=int, default=8)
    m.add_argument("--cache-mb", type=float, default=256.0)
    m.add_argument("--threads", type=int, default=2)
    m.add_argument("--gradient-checkpointing", action="store_true")
    s = sub.add_parser("speed")
    s.add_argument("--resolutions", type=int, nargs="+", default=[64, 128, 256])
    s.add_argument("--batch", type=int, default=8)
    s.add_argument("--patch", type=int, nargs="+", default=[1], help="DDPMConfig.patch values to time")
    s.add_argument("--device", default="cpu", help="cpu | cuda (a measured GPU time instead of the estimate)")
    s.add_argument("--threads", type=int, default=2)
    s.add_argument("--repeats", type=int, default=5)
    s.add_argument("--gpu-tflops", type=float, default=50.0, help="assumed sustained TFLOP/s of a GPU (fp32/TF32 training)")
    s.add_argument("--launch-us", type=float, default=8.0, help="assumed microseconds per GPU kernel launch")
    a = ap.parse_args()
    memory(a) if a.what == "memory" else speed(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
