#!/usr/bin/env python
"""The tables of the avatars on real clips (``bench/eval_real_avatars.py``'s JSON lines) as
Markdown: per protocol, each clip's methods with PSNR / SSIM per region; then, per avatar and clip,
where it wins and loses against the nearest training frame frame by frame (the share of test
frames it beats it on, and its mean margin on the half of the frames the nearest frame matches
worst: the expressions and poses the training frames hold least).

    python bench/real_avatars_table.py bench/results/real_avatars/clips_256.jsonl [more.jsonl ...]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ORDER = ("mean_face", "nearest_frame", "hfm_gs_poses_file", "hfm_gs_poses_image", "thgs")
NAMES = {"mean_face": "mean training face (baseline b)", "nearest_frame": "nearest training frame, warped (baseline a)",
         "hfm_gs_poses_file": "HFM-GS, tracked head pose", "hfm_gs_poses_image": "HFM-GS, pose from the lower-face crop",
         "thgs": "THGS (the clip's sound, tracked poses)"}


def load(path) -> list[dict]:
    rows = {}
    for line in Path(path).read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            key = (r["clip"], r["protocol"], r["method"])
            if key in rows and r.get("train_s") is None:  # rescored: the training time is the first run's
                r["train_s"] = rows[key].get("train_s")
            rows[key] = r  # the last line of a method counts
    return list(rows.values())


def table(rows: list[dict], protocol: str) -> str:
    regs = ("occluded", "person") if protocol == "hfm" else ("face", "mouth")
    head = ["clip", "method"] + [f"{r} PSNR dB / SSIM" for r in regs]
    if protocol == "thgs":
        head += ["mouth opening r: real frames", "r: sound (real frames' own)"]
    head += ["steps (CPU min)"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    clips = sorted({r["clip"] for r in rows if r["protocol"] == protocol})
    for c in clips:
        for m in ORDER:
            r = next((x for x in rows if x["clip"] == c and x["protocol"] == protocol and x["method"] == m), None)
            if r is None:
                continue
            cells = [c, NAMES[m]] + [f"{r[f'psnr_{g}']:.2f} / {r[f'ssim_{g}']:.3f}" for g in regs]
            if protocol == "thgs":
                cells += [f"{r['mouth_gap_corr_real']:.2f}" if "mouth_gap_corr_real" in r else "–",
                          f"{r['lipsync_corr']:.2f} ({r['lipsync_corr_real']:.2f})" if "lipsync_corr" in r else "– (no sound)"]
            cells.append(f"{r['iters']} ({r['train_s'] / 60:.0f})" if r.get("train_s") else "–")
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def wins(rows: list[dict]) -> str:
    out = ["| clip | avatar | region | frames it beats the nearest frame on | margin on the nearest frame's worst half (dB) |",
           "|---|---|---|---|---|"]
    for r in rows:
        if r["method"] not in ("hfm_gs_poses_file", "hfm_gs_poses_image", "thgs"):
            continue
        reg = "occluded" if r["protocol"] == "hfm" else "face"
        nf = next(x for x in rows if x["clip"] == r["clip"] and x["protocol"] == r["protocol"] and x["method"] == "nearest_frame")
        a, b = np.asarray(r[f"psnr_{reg}_frames"], float), np.asarray(nf[f"psnr_{reg}_frames"], float)
        ok = np.isfinite(a) & np.isfinite(b)
        a, b = a[ok], b[ok]
        worst = b <= np.median(b)
        out.append(f"| {r['clip']} | {NAMES[r['method']]} | {reg} | {int((a > b).sum())} of {len(a)} | "
                   f"{float((a[worst] - b[worst]).mean()):+.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    paths = argv or sys.argv[1:] or ["bench/results/real_avatars/clips_256.jsonl"]
    rows = [r for p in paths for r in load(p)]
    print("HFM-GS protocol (a headset drawn over the test frames; its pixels restored)\n")
    print(table(rows, "hfm"))
    print("\nTHGS protocol (the whole test frame predicted)\n")
    print(table(rows, "thgs"))
    print("\nFrame by frame against the nearest training frame\n")
    print(wins(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
