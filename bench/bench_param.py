"""Time the Ricci-flow rectangle map against libigl's harmonic and LSCM maps, in one run.

One JSON line per (mesh, method): vertices, seconds, Newton iterations (ricci), and the
distortion summary (quasi-conformal ratio mean/p95/max, flipped triangles).  Ricci flow
has two lines: ``ricci`` (its vertex UVs interpolated linearly, as renderers and the
geometry images use them; after intrinsic flips these are the chord triangles of the
intrinsic triangulation) and ``ricci_map`` (the discrete conformal map itself, sampled at
``level^2`` points per input triangle: projective per triangle, and carried through the
intrinsic flips when there are any).

    python bench/bench_param.py [--sizes 10000 50000 200000]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def emit(name, n, method, seconds, dist, **extra):
    d = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in dist.items()}
    print(json.dumps({"name": name, "vertices": n, "method": method, "seconds": round(seconds, 4), **extra, **d}), flush=True)


def run(name, V, F):
    from geoface.param import baselines, metrics
    from geoface.param.linsolve import SPDSolver
    from geoface.param.ricci import ricci_flow_rectangle

    t = time.perf_counter()
    r = ricci_flow_rectangle(V, F)
    sec = time.perf_counter() - t
    emit(name, len(V), "ricci", sec, metrics.distortion(r.V, r.F, r.uv).summary(), iterations=r.iterations,
         converged=r.converged, residual=float(f"{r.residual:.3g}"), linear_solver=SPDSolver("auto").method,
         intrinsic_flips=r.intrinsic_flips, split_boundary_edges=int(len(r.split_edges)))
    t = time.perf_counter()
    level = 1 if len(V) > 60000 else 3
    md = metrics.map_distortion(r.V, r.mesh_F, r.map_points, level=level).summary()
    emit(name, len(V), "ricci_map", time.perf_counter() - t, md)
    uv, sec = baselines.timed(baselines.harmonic_rectangle, V, F, r.corners)
    emit(name, len(V), "harmonic", sec, metrics.distortion(V, F, uv).summary())
    uv, sec = baselines.timed(baselines.lscm, V, F)
    emit(name, len(V), "lscm", sec, metrics.distortion(V, F, uv).summary())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 50000, 200000])
    default_meshes = REPO.parent / "shared" / "data" / "meshes"
    ap.add_argument("--meshes", default=str(default_meshes if default_meshes.is_dir() else REPO / "tests" / "data" / "meshes"))
    args = ap.parse_args()
    from geoface.mesh.io import load_mesh
    from geoface.repair import make_disk
    from geoface.synth import procedural_head

    for n in args.sizes:
        h = procedural_head(n_vertices=n, seed=0)
        run(f"head_{n // 1000}k", h.V, h.F)
    for p in sorted(Path(args.meshes).glob("*.obj")):
        m = load_mesh(p)
        d = make_disk(m.V, m.F)
        run(p.stem, d.V, d.F)


if __name__ == "__main__":
    main()
