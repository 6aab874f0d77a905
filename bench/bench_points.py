"""Point clouds through ``geoface convert``: points sampled evenly from a mesh (no normals: they
are estimated), made a surface (screened Poisson, ``geoface.repair.points``) and converted.

One JSON line per cloud: the surface's topology and its distance to the mesh the points came from
(mean, both one-sided maxima, share of the bounding-box diagonal), then the conversion at
``--res`` (one corner set): seconds for the whole ``convert``, Hausdorff of its reconstruction
against the Poisson surface, whether the face was found and the image upright.

    python bench/bench_points.py [--res 256] [--out FILE]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from _results import emitter  # noqa: E402
MESHES = REPO / "tests" / "data" / "meshes"
#: (name, points): the Max Planck bust (closed), the open face scan at two densities, an ICT head
CLOUDS = (("decimated-max.obj", 30000), ("face.obj", 8000), ("face.obj", 30000), ("ict:0", 30000))


def _mesh(name):
    from geoface.mesh.io import load_mesh

    if name.startswith("ict:"):
        from geoface.synth.ict import ict_head

        m = ict_head(seed=int(name[4:]), parts="all")
        return m.V, m.F
    m = load_mesh(MESHES / name)
    return m.V, m.F


def run(name: str, n: int, res: int, tmp: Path) -> dict:
    import trimesh

    from geoface.errors import GeofaceError
    from geoface.mesh.mesh_data import Mesh
    from geoface.mesh.topology import topology_report
    from geoface.pipeline import ConvertOptions, convert, reconstruction_error
    from geoface.repair.points import surface_from_points

    V, F = _mesh(name)
    tm = trimesh.Trimesh(V, F, process=False)
    P, _ = trimesh.sample.sample_surface_even(tm, n, seed=0)
    t = time.perf_counter()
    s = surface_from_points(np.asarray(P))
    poisson_s = time.perf_counter() - t
    rep = topology_report(s.V, s.F)
    err = reconstruction_error(V, F, s.V, s.F)
    row = {"cloud": name, "points": n, "res": res, "poisson_seconds": round(poisson_s, 2),
           "surface_vertices": int(len(s.V)), "components": rep.components, "genus": rep.genus,
           "boundary_loops": rep.boundary_loops, "to_mesh_mean": round(err["mean"], 5),
           "surface_past_mesh_max": round(err["rec_to_ref_max"], 5), "mesh_missed_max": round(err["ref_to_rec_max"], 5)}
    t = time.perf_counter()
    try:
        m = convert(Mesh(s.V, s.F), tmp / f"{name.replace(':', '_')}_{n}", ConvertOptions(res=res), quiet=True)
    except GeofaceError as e:  # recorded: a failure is a result
        return {**row, "ok": False, "error": str(e), "convert_seconds": round(time.perf_counter() - t, 1)}
    st = m["sets"][0]
    return {**row, "ok": True, "convert_seconds": round(time.perf_counter() - t, 1),
            "hausdorff_vs_surface": round(st["reconstruction"]["hausdorff"], 5),
            "face_found": bool(m.get("face", {}).get("found")) if isinstance(m.get("face"), dict) else None,
            "roi_pixel_share": st.get("roi_pixel_share")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=256, help="geometry-image side (256)")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        emit = emitter(a.out)
        for name, n in CLOUDS:
            emit(run(name, n, a.res, Path(d)))


if __name__ == "__main__":
    main()
