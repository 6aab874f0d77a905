"""Million-vertex heads for timing, as scans arrive: a real head (the Max Planck bust,
decimated-max.obj, or an ICT-FaceKit head) Loop-subdivided until it has at least the asked-for
vertex count, decimated back to it by quadric edge collapse (pymeshlab), and displaced along
its normals by Gaussian noise at scan scale (default σ = 0.02% of the bounding-box diagonal,
about 0.06 mm on a head). Written as binary PLY (what scanners write at this size).

    python data_tools/make_dense_head.py OUT.ply [--vertices 2000000] [--source max|ict0] [--noise 2e-4]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def dense_head(vertices: int, source: str = "max", noise: float = 2e-4, seed: int = 0):
    """(V, F) of a head with about ``vertices`` vertices (see module docs)."""
    import pymeshlab

    from geoface.mesh.core import bbox_diagonal, vertex_normals

    if source == "max":
        from geoface.mesh.io import load_mesh

        src = REPO.parent / "shared" / "data" / "meshes" / "decimated-max.obj"
        if not src.is_file():
            src = REPO / "tests" / "data" / "meshes" / "decimated-max.obj"
        m = load_mesh(src)
        V0, F0 = m.V, m.F
    elif source.startswith("ict"):
        sys.path.insert(0, str(REPO / "data_tools"))
        import make_stress_cases as S

        b = S.ict_base(int(source[3:] or 0))
        V0, F0 = b.V, b.F
    else:
        raise SystemExit(f"unknown source {source!r} (max, ict0, ict1, ...)")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(V0, np.float64), np.asarray(F0, np.int32)))
    while ms.current_mesh().vertex_number() < vertices:
        ms.meshing_surface_subdivision_loop(iterations=1, threshold=pymeshlab.PercentageValue(0))
    if ms.current_mesh().vertex_number() > 1.02 * vertices:
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(2 * vertices), preserveboundary=True,
                                                    preservetopology=True, qualityweight=False)
    cur = ms.current_mesh()
    V = np.asarray(cur.vertex_matrix(), np.float64)
    F = np.asarray(cur.face_matrix(), np.int64)
    rng = np.random.default_rng(seed)
    V = V + vertex_normals(V, F) * (noise * bbox_diagonal(V) * rng.standard_normal(len(V)))[:, None]
    return V, F


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--vertices", type=int, default=2_000_000)
    ap.add_argument("--source", default="max")
    ap.add_argument("--noise", type=float, default=2e-4)
    args = ap.parse_args()
    from geoface.mesh.io import Mesh, save_mesh

    V, F = dense_head(args.vertices, args.source, args.noise)
    save_mesh(args.out, Mesh(V, F))
    print(f"wrote {args.out}: {len(V)} vertices, {len(F)} faces")


if __name__ == "__main__":
    main()
