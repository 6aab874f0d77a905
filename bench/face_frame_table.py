"""Markdown tables from the JSON lines of ``bench/bench_face_frame.py``: per head (and kind), how
the frame was found, how far the turned copies' frames are from the unturned one's (worst up and
front angle), the default image's eye line and face centre (worst; from the landmarks found, and
from the true ones), the landmark error where the truth is known (ICT), and the seconds.

    python bench/face_frame_table.py bench/results/face_frame/face_frame_256.jsonl [more.jsonl ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def load(files):
    rows = []
    for f in files:
        rows += [json.loads(line) for line in Path(f).read_text().splitlines() if line.strip()]
    return rows


def _deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _cue(how: str) -> str:
    if how.startswith("the face"):
        return "the face (" + ("face mesh" if "face mesh" in how else "detector") + ")"
    for key, name in (("head template", "template"), ("opening", "opening"), ("flat cut", "flat cut"), ("stands on", "stands on")):
        if key in how:
            return name
    return how[:20]


def _worst(vals, fmt="{:+.1f}°"):
    v = [x for x in vals if x is not None]
    if not v:
        return "–"
    return fmt.format(max(v, key=abs))


def groups(rows, merge_ict: bool = False):
    """Rows by (head, kind); ``merge_ict``: the ICT heads of a kind on one row ("ict0–9"), each
    head's turned copies still compared with its own unturned one."""
    out: dict = {}
    for r in rows:
        mesh = r["mesh"]
        if merge_ict and mesh.startswith("ict"):
            ids = sorted(int(x["mesh"][3:]) for x in rows if x["mesh"].startswith("ict") and x["kind"] == r["kind"])
            mesh = f"ict{ids[0]}–{ids[-1]}" if ids[0] != ids[-1] else f"ict{ids[0]}"
        out.setdefault((mesh, r["kind"]), []).append(r)
    return out


def _angles(rs):
    """Each turned copy's up and front angle to its own unturned head's."""
    base = {r["mesh"]: r for r in rs if r["rotation"] == 0}
    ups, fronts = [], []
    for r in rs:
        b = base.get(r["mesh"])
        if b is not None and r is not b:
            ups.append(_deg(r["up"], b["up"]))
            fronts.append(_deg(r["front"], b["front"]))
    return ups, fronts


def table(rows, merge_ict: bool = False) -> str:
    lines = ["| head | kind | cases | face found | how | worst up / front vs unturned | eye line, worst: found / true | "
             "face centre, worst: found / true | landmarks, mean mm: inner / all 68 | finding the face, s (median / max) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (mesh, kind), rs in groups(rows, merge_ict).items():
        ok = [r for r in rs if r["ok"]]
        ups, fronts = _angles(ok)
        hows = sorted({_cue(r["how"]) for r in ok})
        found = sum(r["face_found"] for r in ok)
        lm = [r for r in ok if r.get("landmark_mm_inner") is not None]
        lm_s = "–" if not lm else f"{np.mean([r['landmark_mm_inner'] for r in lm]):.1f} / {np.mean([r['landmark_mm_all'] for r in lm]):.1f}"
        fs = [r["face_seconds"] for r in ok if r.get("face_seconds") is not None]
        fs_s = "–" if not fs else f"{np.median(fs):.1f} / {max(fs):.1f}"
        failed = len(rs) - len(ok)
        lines.append(
            f"| {mesh} | {kind} | {len(rs)}{f' ({failed} failed)' if failed else ''} | {found} of {len(ok)} | {', '.join(hows)} | "
            f"{max(ups, default=0):.1f}° / {max(fronts, default=0):.1f}° | "
            f"{_worst([r['eye_line_found'] for r in ok])} / {_worst([r['eye_line_true'] for r in ok])} | "
            f"{_worst([r['center_found'] for r in ok], '{:+.3f}')} / {_worst([r['center_true'] for r in ok], '{:+.3f}')} | "
            f"{lm_s} | {fs_s} |")
    return "\n".join(lines)


def summary(rows) -> str:
    ok = [r for r in rows if r["ok"]]
    g = groups(rows)
    within = turned = 0
    for rs in g.values():
        ups, fronts = _angles([r for r in rs if r["ok"]])
        within += sum(1 for a, b in zip(ups, fronts) if max(a, b) <= 2)
        turned += len(ups)
    eye = [r for r in ok if r["eye_line_found"] is not None and abs(r["eye_line_found"]) <= 3]
    cen = [r for r in ok if r["center_found"] is not None and abs(r["center_found"]) <= 0.1]
    eye_t = [r for r in ok if r["eye_line_true"] is not None and abs(r["eye_line_true"]) <= 3]
    cen_t = [r for r in ok if r["center_true"] is not None and abs(r["center_true"]) <= 0.1]
    n_true = sum(r["eye_line_true"] is not None for r in ok)
    added = [r["seconds"] - r["seconds_without_looking"] for r in ok if r.get("seconds_without_looking") is not None]
    face = [r["face_seconds"] for r in ok if r.get("face_seconds") is not None]
    return "\n".join([
        "| cases | converted | face found | turned copies within 2° of the unturned | eye line within ±3° (found / true) | "
        "centre within 10% (found / true) | finding the face, s: median / max | convert with − without looking, s: median / max |",
        "|---|---|---|---|---|---|---|---|",
        f"| {len(rows)} | {len(ok)} | {sum(r['face_found'] for r in ok)} | {within} of {turned} | {len(eye)} of {len(ok)} / {len(eye_t)} of {n_true} | "
        f"{len(cen)} of {len(ok)} / {len(cen_t)} of {n_true} | "
        + (f"{np.median(face):.2f} / {max(face):.2f}" if face else "–") + " | "
        + (f"{np.median(added):.2f} / {max(added):.2f}" if added else "–") + " |"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--merge-ict", action="store_true", help="the ICT heads of a kind on one row")
    a = ap.parse_args(argv)
    rows = load(a.files)
    print(summary(rows))
    print()
    print(table(rows, a.merge_ict))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
