"""The tables of docs/video.md from the results files (test people's means for the ICT renders;
one row per clip for the real clips).

    python bench/capture_table.py [--ict bench/results/head_track/ict_512.jsonl]
                                  [--ict-extra bench/results/head_track/ict_512_known_focal.jsonl]
                                  [--clips bench/results/capture/clips_512.jsonl]

``--ict-extra``: rows of methods the first file does not have (the refinement with the focal
length given), added to its tables.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAMES = {("pnp68_true_head_true_camera", "known"): "PnP on MediaPipe's 68, true head and camera (oracle)",
         ("rigid468_true_shape_true_camera", "known"): "landmarks' floor: PnP on the 468, true shape, expressions, camera (oracle)",
         ("ict_head_track", "estimated"): "**ICT head track**, focal fitted",
         ("ict_head_track", "known"): "ICT head track, focal given",
         ("ict_head_track_refined_unlit", "estimated"): "+ pixels, one colour per point, identity kept",
         ("ict_head_track_refined_coarse", "estimated"): "+ pixels, lit, identity refined, blurred 2 then 1 px",
         ("ict_head_track_refined", "estimated"): "**+ pixels, lit, identity refined, on to the sharp frame** (`--refine`)",
         ("ict_head_track_refined", "known"): "the same, focal given (`--refine-focal known`)"}


def ict_table(path: Path, split: str = "test", extra: Path | None = None) -> str:
    def read(p):
        rows = [json.loads(x) for x in p.read_text().splitlines() if x.strip()]
        by = defaultdict(list)
        for r in rows:
            if r.get("split") == split and "rot_mean_deg" in r:
                by[(r["method"], r.get("focal", "known"))].append(r)
        return by

    by = read(path)
    if extra is not None and extra.is_file():
        by.update({k: v for k, v in read(extra).items() if k not in by})
    rows = [r for rs in by.values() for r in rs]
    seeds = sorted({r["seed"] for r in rows})
    out = [f"| {split} people {', '.join(map(str, seeds))} | rotation, model frame, mean / p95 ° | the head's motion, "
           "mean / p95 ° | translation mm | after the one scale mm | the face centre's motion mm | face shape mm | "
           "vertices mm | expression r |",
           "|---|---|---|---|---|---|---|---|---|"]

    def m(rs, k, d=2):
        v = [r[k] for r in rs if r.get(k) is not None]
        return "—" if not v else f"{sum(v) / len(v):.{d}f}"

    for key, name in NAMES.items():
        rs = by.get(key)
        if not rs:
            continue
        out.append(f"| {name} | {m(rs, 'rot_mean_deg')} / {m(rs, 'rot_p95_deg')} | {m(rs, 'rot_motion_mean_deg')} / "
                   f"{m(rs, 'rot_motion_p95_deg')} | {m(rs, 'trans_mean_mm', 1)} | {m(rs, 'trans_scaled_mean_mm', 1)} | "
                   f"{m(rs, 'trans_motion_mean_mm', 1)} | {m(rs, 'shape_mean_mm')} | {m(rs, 'vertex_mean_mm', 1)} | {m(rs, 'expr_corr')} |")
    return "\n".join(out)


def clips_table(path: Path) -> str:
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    by = defaultdict(dict)
    for r in rows:
        by[r["clip"]][r["what"]] = r
    out = ["| clip | frames (face found) | held-out points: track mean / p95 px | baseline (mean head, PnP) mean / p95 px | "
           "photometric error before → after refinement (frames) |", "|---|---|---|---|---|"]
    for clip, d in by.items():
        c, h, p = d.get("capture", {}), d.get("held_out_points", {}), d.get("photometric_refinement")
        ref = f"{p['photo_err_before']:.3f} → {p['photo_err_after']:.3f} ({p['frames']})" if p else "—"
        out.append(f"| {clip} | {c.get('frames')} ({c.get('found')}) | {h['track_mean_px']:.2f} / {h['track_p95_px']:.2f} | "
                   f"{h['baseline_mean_px']:.2f} / {h['baseline_p95_px']:.2f} | {ref} |")
    return "\n".join(out)


def speed_table(path: Path) -> str:
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    out = ["| clip | frames | decode + face mesh + masks s | head track s (frames/s) | head mesh s | written s | "
           "wall s |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        sec = r["seconds"]
        out.append(f"| {r['clip']} | {r['frames']} | {sec['decode'] + sec['landmarks'] + sec['masks']:.1f} | "
                   f"{sec['head_track']:.1f} ({r['head_track_fps']:.1f}) | {sec['head_mesh']:.1f} | {sec['write']:.1f} | "
                   f"{r['wall_s']:.1f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ict", default=str(ROOT / "bench/results/head_track/ict_512.jsonl"))
    ap.add_argument("--ict-extra", default=str(ROOT / "bench/results/head_track/ict_512_known_focal.jsonl"))
    ap.add_argument("--clips", default=str(ROOT / "bench/results/capture/clips_512.jsonl"))
    ap.add_argument("--speed", default=str(ROOT / "bench/results/capture/speed_512.jsonl"))
    a = ap.parse_args(argv)
    if Path(a.ict).is_file():
        print(ict_table(Path(a.ict), extra=Path(a.ict_extra)), "\n")
        print(ict_table(Path(a.ict), "val", Path(a.ict_extra)), "\n")
    if Path(a.clips).is_file():
        print(clips_table(Path(a.clips)), "\n")
    if Path(a.speed).is_file():
        print(speed_table(Path(a.speed)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
