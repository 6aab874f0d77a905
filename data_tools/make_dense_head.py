"""Million-vertex heads for timing, as scans arrive: a real head (the Max Planck bust,
decimated-max.obj, or an ICT-FaceKit head) Loop-subdivided until it has at least the asked-for
vertex count, decimated back to it by quadric edge collapse (pymeshlab), and displaced along
its normals by Gaussian noise at scan scale (default σ = 0.02% of the bounding-box diagonal,
about 0.06 mm on a head). Written as binary PLY (what scanners write at this size).

``--scan`` makes it look like a raw scan rather than a clean copy (:func:`scan_like`): holes where
the scanner saw nothing, a ragged rim at the bottom instead of a clean cut, floating debris and a
loose fragment, uneven triangles (a patch decimated coarser than the rest) and a little noise
more on top.

    python data_tools/make_dense_head.py OUT.ply [--vertices 2000000] [--source max|ict0] [--noise 2e-4] [--scan]
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


def scan_like(V, F, seed: int = 0, holes: int = 12, debris: int = 6):
    """A clean dense head made scan-like (module docs): ``holes`` holes of 0.5–2% of the diagonal
    in radius, the lowest 8% of the height cut away along a ragged line, the back of the head
    decimated to a third of its density, ``debris`` small floating blobs and one detached
    fragment near the shoulders. Returns (V, F); the vertex count falls by a few percent."""
    import pymeshlab

    from geoface.mesh.core import bbox_diagonal

    rng = np.random.default_rng([seed, 134])
    V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
    diag = bbox_diagonal(V)
    up = np.array([0.0, 1.0, 0.0])
    C = V[F].mean(1)
    keep = np.ones(len(F), bool)
    # a ragged rim: the bottom cut along a height that wanders by +-1.5% of the diagonal
    h = C @ up
    ang = np.arctan2(C[:, 2] - V[:, 2].mean(), C[:, 0] - V[:, 0].mean())
    wobble = sum(rng.uniform(0.002, 0.006) * diag * np.sin(k * ang + rng.uniform(0, 2 * np.pi)) for k in (3, 7, 13, 29))
    keep &= h > h.min() + 0.08 * np.ptp(h) + wobble
    # holes where the scanner saw nothing
    for c in C[rng.choice(np.flatnonzero(keep), holes, replace=False)]:
        keep &= np.linalg.norm(C - c, axis=1) > rng.uniform(0.005, 0.02) * diag
    F = F[keep]
    used = np.unique(F)
    remap = -np.ones(len(V), np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    # uneven triangles: the back of the head (the bust faces -Z) decimated to a third of its density
    back = (V[:, 2] > np.median(V[:, 2]) + 0.1 * np.ptp(V[:, 2])).astype(np.float64)
    m = pymeshlab.Mesh(V, F.astype(np.int32), v_scalar_array=back)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(m)
    ms.compute_selection_by_condition_per_vertex(condselect="q > 0.5")
    ms.compute_selection_transfer_vertex_to_face(inclusive=False)
    n_back = int(ms.current_mesh().selected_face_number())
    if n_back > 1000:
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(len(F) - n_back * 2 // 3), selected=True,
                                                    preserveboundary=True, preservetopology=True, qualityweight=False)
    cur = ms.current_mesh()
    V = np.asarray(cur.vertex_matrix(), np.float64)
    F = np.asarray(cur.face_matrix(), np.int64)
    # debris and a loose fragment, as a scanner's stray returns and a bit of the stand
    parts_V, parts_F, n = [V], [F], len(V)
    lo, hi = V.min(0), V.max(0)
    for k in range(debris + 1):
        s = pymeshlab.MeshSet()
        s.create_sphere(subdiv=2 if k < debris else 3)
        b = s.current_mesh()
        r = (0.004 if k < debris else 0.03) * diag
        centre = lo + rng.uniform(0, 1, 3) * (hi - lo)
        if k == debris:
            centre[1] = lo[1] - 0.05 * diag
        Vb = np.asarray(b.vertex_matrix()) * r * rng.uniform(0.7, 1.3, 3) + centre
        parts_V.append(Vb)
        parts_F.append(np.asarray(b.face_matrix(), np.int64) + n)
        n += len(Vb)
    V, F = np.concatenate(parts_V), np.concatenate(parts_F)
    return V + rng.normal(0, 5e-5 * diag, V.shape), F


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--vertices", type=int, default=2_000_000)
    ap.add_argument("--source", default="max")
    ap.add_argument("--noise", type=float, default=2e-4)
    ap.add_argument("--scan", action="store_true", help="make it look like a raw scan (holes, ragged rim, debris)")
    args = ap.parse_args()
    from geoface.mesh.io import Mesh, save_mesh

    V, F = dense_head(args.vertices, args.source, args.noise)
    if args.scan:
        V, F = scan_like(V, F)
    save_mesh(args.out, Mesh(V, F))
    print(f"wrote {args.out}: {len(V)} vertices, {len(F)} faces")


if __name__ == "__main__":
    main()
