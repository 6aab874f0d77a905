#!/usr/bin/env python
"""Summarise ``eval_texture.py`` runs that differ only in the model seed (``--seed``).

    python bench/texture_seeds.py RESULTS.jsonl [RESULTS.jsonl ...] [--split test] [--a gde_hfdr --b gde_hfdr_no_hash]

Each file is one seed's ``results.jsonl`` (the same held-out faces in every run; where a face
was scored more than once, its last row counts).  ``OLD.jsonl+NEW.jsonl`` reads both files as
one seed's run, NEW's rows after OLD's: a run made with ``eval_texture.py --no-ablation`` (the
model with hash encoding only) then takes its no-hash rows from an earlier run of the same data
and seed. Prints one JSON line per variant and split:
the mean over faces of each seed, then their mean and standard deviation over seeds; and, for
the pair ``--a`` − ``--b`` (default the model with and without hash encoding, and the same for
the GDE alone), per metric: the difference of each seed, their mean, its standard error over
seeds, how many seeds and how many (seed, face) pairs ``--a`` wins.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

METRICS = ("albedo_psnr", "albedo_ssim", "albedo_detail_psnr", "micronormal_psnr", "micronormal_detail_psnr",
           "specular_psnr", "specular_detail_psnr")
PAIRS = (("gde_hfdr", "gde_hfdr_no_hash"), ("gde_upsampled", "gde_upsampled_no_hash"))


def per_face(spec: str) -> dict:
    """{(split, variant): {face: row}} from one results.jsonl, or several joined by "+" (last
    row per face wins)."""
    out: dict = {}
    lines = [line for p in spec.split("+") for line in Path(p).read_text().splitlines()]
    for line in lines:
        r = json.loads(line)
        if r.get("stage") == "face":
            out.setdefault((r["split"], r["variant"]), {})[r["face"]] = r
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="one results.jsonl per seed (OLD.jsonl+NEW.jsonl: both, NEW last)")
    ap.add_argument("--splits", default="val,test")
    ap.add_argument("--a", default=None, help="variant compared (default: both hash pairs)")
    ap.add_argument("--b", default=None, help="against this variant")
    a = ap.parse_args(argv)
    runs = [per_face(p) for p in a.results]
    pairs = [(a.a, a.b)] if a.a and a.b else list(PAIRS)
    for split in a.splits.split(","):
        keys = [k for k in runs[0] if k[0] == split]
        faces = {k: sorted(set.intersection(*(set(r.get(k, {})) for r in runs))) for k in keys}
        if not keys or not all(faces.values()):
            print(f"texture_seeds: no faces of split {split!r} common to all runs", file=sys.stderr)
            return 2
        for _, v in keys:
            means = np.array([[np.mean([r[(split, v)][f][m] for f in faces[(split, v)]]) for m in METRICS] for r in runs])
            print(json.dumps({"split": split, "variant": v, "seeds": len(runs), "faces": len(faces[(split, v)]),
                              **{m: [round(float(x), 3) for x in means[:, i]] for i, m in enumerate(METRICS)},
                              **{f"{m}_mean": round(float(means[:, i].mean()), 3) for i, m in enumerate(METRICS)},
                              **{f"{m}_sd": round(float(means[:, i].std(ddof=1)), 3) if len(runs) > 1 else None
                                 for i, m in enumerate(METRICS)}}))
        for va, vb in pairs:
            if (split, va) not in faces or (split, vb) not in faces:
                continue
            common = sorted(set(faces[(split, va)]) & set(faces[(split, vb)]))
            row = {"split": split, "pair": f"{va} - {vb}", "seeds": len(runs), "faces": len(common)}
            for m in METRICS:
                d = np.array([[r[(split, va)][f][m] - r[(split, vb)][f][m] for f in common] for r in runs])
                per_seed = d.mean(1)
                row[m] = {"per_seed": [round(float(x), 3) for x in per_seed], "mean": round(float(per_seed.mean()), 3),
                          "se": round(float(per_seed.std(ddof=1) / np.sqrt(len(runs))), 3) if len(runs) > 1 else None,
                          "seeds_won": int((per_seed > 0).sum()), "faces_won": int((d > 0).sum()), "pairs": int(d.size)}
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
