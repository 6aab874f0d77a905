#!/usr/bin/env python
"""Training speed of THGS on a talking capture, per device: one JSON line each.

    python bench/bench_thgs_train.py DATA_DIR [--iters 300] [--devices cpu,cuda] [--threads N]

Times ``--iters`` training steps with the default configuration, its stages scaled so that every
part (LEB, SAAM, the audio articulation) trains within the run, and reports the steps per second
over the second half (after the stages have all started and the first CUDA kernels are built).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    import torch

    from geoface.thgs.model import PAPER_STAGES, THGSConfig
    from geoface.thgs.train import train_thgs

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data_dir")
    ap.add_argument("--iters", type=int, default=300)
    ap.add_argument("--devices", default="cpu")
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    scale = 0.4 * a.iters / PAPER_STAGES[-1]  # SAAM (the last stage) from 40 % of the run
    for dev in a.devices.split(","):
        marks = []
        cfg = THGSConfig(iters=a.iters, stage_scale=scale)
        with tempfile.TemporaryDirectory() as tmp:
            info = train_thgs(a.data_dir, Path(tmp) / "m", cfg, device=dev,
                              progress=lambda it, row: marks.append((it, time.perf_counter())))
        (i0, t0), (i1, t1) = marks[len(marks) // 2], marks[-1]
        print(json.dumps({"bench": "thgs_train", "device": dev,
                          "gpu": torch.cuda.get_device_name() if dev.startswith("cuda") else None,
                          "threads": torch.get_num_threads(), "iters": a.iters, "gaussians": info["n_gaussians"],
                          "seconds": round(info["seconds"], 1), "steps_per_s": round((i1 - i0) / (t1 - t0), 2)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
