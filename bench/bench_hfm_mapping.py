#!/usr/bin/env python
"""HFM-GS Table 3 on this machine: time and memory of the half-face mapping with and without
correlation-weight sampling, at 40K, 70K and 100K Gaussians.

One JSON line per (Gaussians, sampling): the median seconds of one inference ``deform`` (the
whole per-frame Gaussian path: lower MLPs, mapping, composition, global pose) and of the mapping
alone (upper deformations from lower ones: 512 × 512 keys, W_dist upsampling and, with the default
``upsample="features"``, MLP_mapping at every upper Gaussian; or W_gm over all upper × lower
Gaussians in row chunks), the one-off key selection (after each densification), and
the peak RSS above the RSS before the first call (VmHWM reset; each case in a fresh process).
Gaussians: one per vertex of the procedural head with that many vertices, split at the eye/nose
plane as in training; random (untrained) network weights — the cost does not depend on them.

    python bench/bench_hfm_mapping.py [--sizes 40000 70000 100000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _status_mib(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    raise KeyError(key)


def child(n: int, sampling: bool, repeats: int) -> dict:
    import torch

    from geoface.splat.gaussians import Gaussians
    from geoface.hfm import HFMConfig, HFMModel
    from geoface.synth.head import HeadModel

    torch.manual_seed(0)
    hm = HeadModel(n_vertices=n, seed=0)
    h = hm.mesh()
    y_eye, y_nose = h.eye_line_y, float(h.V[h.landmarks["nose_tip"], 1])
    g = Gaussians.from_mesh(h.V, h.F, h.colors[:, :3])
    model = HFMModel(g, HFMConfig(sampling=sampling), y_eye - 0.4 * (y_eye - y_nose))
    for m in model.modules():  # untrained weights, but not the zero-initialised identity
        if isinstance(m, torch.nn.Linear):
            torch.nn.init.normal_(m.weight, std=0.05)
    model.eval()
    theta = torch.randn(1, model.cfg.latent_dim)
    up = model.upper_mask()
    iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
    Path("/proc/self/clear_refs").write_text("5")
    base = _status_mib("VmRSS")
    with torch.no_grad():
        t = time.perf_counter()
        model.refresh_keys()
        t_keys = time.perf_counter() - t
        E = model.embed(g.means)
        pL = model.lower_params(E[il], theta)
        full, mapping = [], []
        if sampling:  # rows of pL for the lower keys (bookkeeping, outside the timed region)
            pos = torch.full((len(g),), -1, dtype=torch.long)
            pos[il] = torch.arange(len(il))
            rows = pos[model.keys_l]
        for _ in range(repeats + 1):
            t = time.perf_counter()
            model.deform(theta)
            full.append(time.perf_counter() - t)
            t = time.perf_counter()
            if sampling:
                model.map_keys(E, iu, pL[rows])
            else:
                model.map_params(E[iu], E[il], pL)
            mapping.append(time.perf_counter() - t)
    peak = _status_mib("VmHWM")
    med = lambda xs: round(statistics.median(xs[1:]), 4)  # noqa: E731
    return {"gaussians": len(g), "upper": len(iu), "lower": len(il), "sampling": sampling,
            "deform_s": med(full), "mapping_s": med(mapping), "key_selection_s": round(t_keys, 4) if sampling else 0.0,
            "peak_rss_above_mib": round(peak - base, 1), "threads": torch.get_num_threads()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[40_000, 70_000, 100_000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--_child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._child:
        print(json.dumps(child(int(a._child[0]), a._child[1] == "1", int(a._child[2]))))
        return
    for n in a.sizes:
        for s in (True, False):
            r = subprocess.run([sys.executable, __file__, "--_child", str(n), "1" if s else "0", str(a.repeats)],
                               capture_output=True, text=True)
            if r.returncode:
                row = {"gaussians": n, "sampling": s, "error": (r.stderr.strip().splitlines() or ["?"])[-1]}
            else:
                row = json.loads(r.stdout.strip().splitlines()[-1])
            print(json.dumps({"name": "hfm_mapping", **row}), flush=True)


if __name__ == "__main__":
    main()
