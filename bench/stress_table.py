"""Markdown tables from the JSON lines of ``bench/bench_stress.py``: one row per case and
resolution (the frame found, the conformal factor's range, the OT path and iterations, whole and
face Hausdorff, the face-pixel share, seconds, whether the face is upright), and a summary.

    python bench/stress_table.py bench/results/stress/stress_256.jsonl [more.jsonl ...]
    python bench/stress_table.py stress_512.jsonl stress_512_conventions.jsonl --conventions --summary-only
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

PATHS = {"ot": "OT", "ot+convex-combination": "OT+cc", "balanced+ot": "bal+OT", "balanced+ot+convex-combination": "bal+OT+cc",
         "balanced": "balanced only"}


def load(files):
    rows = []
    for f in files:
        for line in Path(f).read_text().splitlines():
            if line.strip():
                rows.append(json.loads(line))
    return rows


def _pct(x, digits=2):
    return "–" if x is None else f"{100 * x:.{digits}f}%"


def _frame(r):
    fr = r.get("frame") or {}
    how = fr.get("how", "")
    cue = ("template" if "template" in how else "opening" if "opening" in how else "stands on" if "stands on" in how
           else "flat cut" if "flat cut" in how else "long axis" if "long axis" in how else "file +Y" if "+Y" in how else how[:12])
    return f"{cue}{'' if fr.get('certain', True) else ' (uncertain)'}"


def _tilt(r):
    """The eye line's angle to the image rows in the default image (degrees), or None."""
    import math

    p = r.get("landmark_pixels") or {}
    if "eye_right" not in p or "eye_left" not in p:
        return None
    return math.degrees(math.atan2(p["eye_left"][0] - p["eye_right"][0], p["eye_left"][1] - p["eye_right"][1]))


def _upright(r):
    if "upright_problems" not in r:
        return "–"
    return "yes" if not r["upright_problems"] else "NO: " + "; ".join(r["upright_problems"])


def table(rows) -> str:
    out = ["| case | kind | convention | N | up found | up err ° | log conf. range | OT path (sets) | OT it. | flips | "
           "Hausdorff (worst set) | face Hausdorff (worst) | face pixels | upright | s (8 sets) |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if not r["ok"]:
            out.append(f"| {r['case']} | {r['kind']} | {r['convention']} | {r['res']} | FAILED: {r['error']} |" + " |" * 10)
            continue
        paths = ", ".join(PATHS.get(p, p) for p in r["ot_paths"])
        lost = f", {len(r['failed_sets'])} sets lost" if r["failed_sets"] else ""
        out.append(f"| {r['case']} | {r['kind']} | {r['convention']} | {r['res']} | {_frame(r)} | {r['up_error_deg']:.1f} | "
                   f"{r['log_conformal_range']:.1f} | {paths}{lost} | {r['ot_iterations']} | {r['flipped']} | "
                   f"{_pct(r['hausdorff'])} | {_pct(r['face_hausdorff'])} | {_pct(r['roi_pixel_share'], 1)} | {_upright(r)} | "
                   f"{r['seconds']:.0f} |")
    return "\n".join(out)


def summary(rows) -> str:
    out = ["| N | cases | converted | corner sets lost | OT paths (cases) | flipped triangles | face upright (heads) | "
           "Hausdorff ≤ 0.5% | face ≤ 0.2% |", "|---|---|---|---|---|---|---|---|---|"]
    for res in sorted({r["res"] for r in rows}):
        rs = [r for r in rows if r["res"] == res]
        ok = [r for r in rs if r["ok"]]
        lost = sum(len(r["failed_sets"]) for r in ok)
        paths: dict = {}
        for r in ok:
            for p in r["ot_paths"]:
                paths[PATHS.get(p, p)] = paths.get(PATHS.get(p, p), 0) + 1
        heads = [r for r in ok if "upright_problems" in r]
        up = sum(1 for r in heads if not r["upright_problems"])
        h = sum(1 for r in ok if r["hausdorff"] <= 0.005)
        fh = [r for r in ok if r["face_hausdorff"] is not None]
        f = sum(1 for r in fh if r["face_hausdorff"] <= 0.002)
        out.append(f"| {res} | {len(rs)} | {len(ok)} | {lost} | {', '.join(f'{k} {v}' for k, v in sorted(paths.items()))} | "
                   f"{sum(r['flipped'] for r in ok)} | {up} of {len(heads)} | {h} of {len(ok)} | {f} of {len(fh)} |")
    return "\n".join(out)


def per_base(rows) -> str:
    """One row per source mesh and resolution: its cases (conventions and stress kinds), the
    worst and median whole-mesh Hausdorff (worst corner set of each case), the worst face
    Hausdorff, and where the worst case came from."""
    out = ["| mesh | N | cases | all 8 sets | flips | whole Hausdorff: median / worst (case) | face Hausdorff: worst (case) | upright "
           "(eye line, worst) |", "|---|---|---|---|---|---|---|---|"]
    import statistics

    keys = sorted({(r["base"], r["res"]) for r in rows}, key=lambda k: (k[1], k[0].startswith("ict"), k[0]))
    # ICT heads with one case each (no variants) share a row
    single = [k for k in keys if k[0].startswith("ict") and sum(1 for r in rows if (r["base"], r["res"]) == k) == 1]
    groups = [(k[0], k[1], [k[0]]) for k in keys if k not in single]
    for res in sorted({k[1] for k in single}):
        names = [k[0] for k in single if k[1] == res]
        groups.append((names[0] if len(names) == 1 else f"{names[0]}–{names[-1]}", res, names))
    for base, res, members in groups:
        rs = [r for r in rows if r["base"] in members and r["res"] == res]
        ok = [r for r in rs if r["ok"]]
        full = sum(1 for r in ok if not r["failed_sets"])
        hw = max(ok, key=lambda r: r["hausdorff"]) if ok else None
        fr = [r for r in ok if r["face_hausdorff"] is not None]
        fw = max(fr, key=lambda r: r["face_hausdorff"]) if fr else None
        heads = [r for r in ok if "upright_problems" in r]
        up = f"{sum(1 for r in heads if not r['upright_problems'])} of {len(heads)}" if heads else "–"
        tilts = [t for t in (_tilt(r) for r in heads) if t is not None]
        if tilts:
            up += f" ({max(tilts, key=abs):+.0f}°)"
        med = statistics.median(r["hausdorff"] for r in ok) if ok else None
        out.append(f"| {base} | {res} | {len(rs)} | {full} | {sum(r['flipped'] for r in ok)} | "
                   f"{_pct(med)} / {_pct(hw['hausdorff']) if hw else '–'} ({hw['case'] if hw else ''}) | "
                   f"{_pct(fw['face_hausdorff']) + ' (' + fw['case'] + ')' if fw else '–'} | {up} |")
    return "\n".join(out)


def by_convention(rows) -> str:
    """The cases that move a mesh into another axis convention: one row per mesh (and ICT
    variant) and resolution seen in more than one convention, one column per convention, each cell the worst whole / face
    Hausdorff of the 8 sets (``!`` marks a case that failed, lost a set or was not upright)."""
    conv = [c for c in CONVENTION_ORDER if any(r["convention"] == c for r in rows)]
    out = ["| mesh | N | " + " | ".join(conv) + " |", "|---|---|" + "---|" * len(conv)]
    cells: dict = {}
    for r in rows:
        if r["kind"] not in ("base", "axes"):
            continue
        name = r["case"][: -len(r["convention"]) - 1] if r["case"].endswith("_" + r["convention"]) else r["case"]
        if not r["ok"]:
            cell = "FAILED"
        else:
            bad = r["failed_sets"] or r["flipped"] or r.get("upright_problems")
            cell = f"{100 * r['hausdorff']:.2f} / {_pct(r['face_hausdorff'])}{' !' if bad else ''}"
        cells[(name, r["res"], r["convention"])] = cell
    keys = sorted({(k[0], k[1]) for k in cells if sum(1 for c in conv if (k[0], k[1], c) in cells) > 1},
                  key=lambda k: (k[1], k[0].startswith("ict"), k[0]))
    for name, res in keys:
        out.append(f"| {name} | {res} | " + " | ".join(cells.get((name, res, c), "–") for c in conv) + " |")
    return "\n".join(out)


#: column order of :func:`by_convention`
CONVENTION_ORDER = ("y-up", "z-up+x", "z-up-y", "x-up", "-x-up", "-y-up", "-z-up", "y-up-x", "tilted-mm-far")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--summary-only", action="store_true")
    ap.add_argument("--per-mesh", action="store_true", help="also the table of one row per source mesh")
    ap.add_argument("--conventions", action="store_true", help="also the table of one column per axis convention")
    args = ap.parse_args()
    rows = load(args.files)
    print(summary(rows))
    if args.per_mesh:
        print()
        print(per_base(rows))
    if args.conventions:
        print()
        print(by_convention(rows))
    if not args.summary_only:
        print()
        print(table(rows))


if __name__ == "__main__":
    main()
