"""A dense real scan for timing: the Max Planck bust (decimated-max.obj, 5.3K vertices)
subdivided (Loop) and remeshed isotropically to about 134K vertices (target 140K: the remesher lands ~5% below) with pymeshlab.

    python data_tools/make_dense_bust.py OUT.obj [--vertices 134000]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--vertices", type=int, default=140000)
    ap.add_argument("--source", default=str(REPO.parent / "shared" / "data" / "meshes" / "decimated-max.obj"))
    args = ap.parse_args()
    import pymeshlab

    from geoface.mesh.io import Mesh, load_mesh, save_mesh
    from geoface.repair.remesh import remesh

    src = Path(args.source)
    if not src.is_file():
        src = REPO / "tests" / "data" / "meshes" / "decimated-max.obj"
    m = load_mesh(src)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(m.V, m.F))
    ms.meshing_surface_subdivision_loop(iterations=3)
    cur = ms.current_mesh()
    r = remesh(cur.vertex_matrix(), cur.face_matrix(), args.vertices)
    save_mesh(args.out, Mesh(r.V, r.F))
    print(f"wrote {args.out}: {len(r.V)} vertices, {len(r.F)} faces")


if __name__ == "__main__":
    main()
