"""What the fold-free step's untangle-and-relax path (``geoface.param.foldfree``: a map whose
whole convex-combination solve loses much of the wanted areas is also untangled where it folds
and relaxed towards the masses; the map losing less is kept) buys on a real mesh with limbs:
male02 (a clothed man, ``../shared/data/meshes``), every corner set converted at ``--res`` twice
— as shipped, and with the untangle path switched off (the whole solve kept, as before it
existed).

One JSON line per corner set: which solve was kept (``fold_free_solve``), the reconstruction's
Hausdorff distance (share of the bounding-box diagonal: whole surface and face), the largest
vertex displacement of the fold-free step, the area error after it, and ``before_hausdorff``:
the whole-solve-only run's Hausdorff of the same set.

    python bench/bench_untangle.py [--mesh ../shared/data/meshes/male02.obj] [--res 512] [--out FILE]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _results import emitter  # noqa: E402

MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"


def run(mesh_path: Path, res: int, untangle: bool, tmp: Path) -> list[dict]:
    import geoface.param.foldfree as ff
    from geoface.mesh.io import load_mesh
    from geoface.pipeline import ConvertOptions, convert

    saved = ff.UNTANGLE_MIN_LOSS, ff.REFINED_MIN_LOSS
    if not untangle:
        ff.UNTANGLE_MIN_LOSS = ff.REFINED_MIN_LOSS = float("inf")
    try:
        m = convert(load_mesh(mesh_path), tmp / ("on" if untangle else "off"), ConvertOptions(res=res, augment=8),
                    quiet=True)
    finally:
        ff.UNTANGLE_MIN_LOSS, ff.REFINED_MIN_LOSS = saved
    return m["sets"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", type=Path, default=MESHES / "male02.obj", help="the mesh (default: male02)")
    ap.add_argument("--res", type=int, default=512, help="geometry-image side (default 512)")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        on = run(a.mesh, a.res, True, Path(d))
        off = run(a.mesh, a.res, False, Path(d))
    before = {s["corner_set"]: s["reconstruction"]["hausdorff"] for s in off}
    emit = emitter(a.out)
    for s in on:
        row = {"bench": "male02_untangle" if a.mesh.stem == "male02" else "untangle", "mesh": a.mesh.name, "res": a.res,
               "corner_set": s["corner_set"], "fold_free_solve": s["ot"]["fold_free_solve"], "ot_path": s["ot"]["path"],
               "hausdorff": round(s["reconstruction"]["hausdorff"], 5),
               "face_hausdorff": (None if s["reconstruction"].get("face_hausdorff") is None
                                  else round(s["reconstruction"]["face_hausdorff"], 5)),
               "max_displacement": round(s["ot"]["max_displacement"], 4),
               "area_error_after": round(s["ot"]["area_error_after"], 4),
               "before_hausdorff": None if s["corner_set"] not in before else round(before[s["corner_set"]], 5)}
        emit(row)


if __name__ == "__main__":
    main()
