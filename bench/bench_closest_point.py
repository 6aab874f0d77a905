"""The reconstruction error report's closest-point queries: libigl against open3d, at equal accuracy.

    python bench/bench_closest_point.py [--sizes 10000 134000] [--res 512]

For a procedural head of each size (the reference) and its reconstruction from a geometry image
of ``--res``² (the query mesh; :func:`geoface.convert`'s report measures both sides), the
two-sided vertex-to-surface distances by

* ``igl_point_mesh``: ``igl.point_mesh_squared_distance`` (what the report used: a tree built per call);
* ``igl_aabb``: an explicit ``igl.AABB`` tree, built once per side, then queried;
* ``open3d_raycasting``: ``open3d.t.geometry.RaycastingScene.compute_distance`` (Embree BVH, float32);

one JSON line per method and size: build and query seconds (median of ``--repeats``), and the
largest difference from libigl's distances over the bounding-box diagonal (the accuracy the
Hausdorff report needs is 1e-5 of the diagonal: its figures are printed to 0.01 %).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _pair(n: int, res: int):
    from geoface.gimage import geometry_image, reconstruct
    from geoface.param.baselines import harmonic_rectangle
    from geoface.repair import make_disk
    from geoface.synth import procedural_head

    head = procedural_head(n_vertices=n, seed=0)
    disk = make_disk(head.V, head.F, quiet=True)
    uv = harmonic_rectangle(disk.V, disk.F)  # the query mesh only has to be a realistic reconstruction
    gi = geometry_image(disk.V, disk.F, uv, res)
    rec = reconstruct(gi)
    return (disk.V, disk.F), (rec.V, rec.F)


def _time(fn, repeats):
    ts, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 134000])
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    import igl

    try:
        import open3d as o3d
    except ImportError:
        o3d = None
    for n in a.sizes:
        (Vr, Fr), (Vq, Fq) = _pair(n, a.res)
        diag = float(np.linalg.norm(Vr.max(0) - Vr.min(0)))
        sides = [(Vq, Vr, Fr), (Vr, Vq, Fq)]  # queries, mesh
        base = [np.sqrt(igl.point_mesh_squared_distance(P, V, F)[0]) for P, V, F in sides]
        common = {"reference_vertices": len(Vr), "reconstruction_vertices": len(Vq), "res": a.res}

        def igl_point_mesh():
            return [np.sqrt(igl.point_mesh_squared_distance(P, V, F)[0]) for P, V, F in sides]

        def igl_trees():
            trees = []
            for _, V, F in sides:
                t = igl.AABB()
                t.init(V, F)
                trees.append(t)
            return trees

        def open3d_scenes():
            scenes = []
            for _, V, F in sides:
                s = o3d.t.geometry.RaycastingScene()
                s.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
                scenes.append(s)
            return scenes

        rows = []
        q_s, d = _time(igl_point_mesh, a.repeats)
        rows.append(("igl_point_mesh", 0.0, q_s, d))
        b_s, trees = _time(igl_trees, a.repeats)
        q_s, d = _time(lambda: [np.sqrt(np.maximum(t.squared_distance(V, F, P)[0], 0)).ravel()
                                for t, (P, V, F) in zip(trees, sides)], a.repeats)
        rows.append(("igl_aabb", b_s, q_s, d))
        if o3d is not None:
            b_s, scenes = _time(open3d_scenes, a.repeats)
            q_s, d = _time(lambda: [s.compute_distance(o3d.core.Tensor(P.astype(np.float32))).numpy().astype(np.float64)
                                    for s, (P, _, _) in zip(scenes, sides)], a.repeats)
            rows.append(("open3d_raycasting", b_s, q_s, d))
        for name, b_s, q_s, d in rows:
            err = max(float(np.abs(x - y).max()) for x, y in zip(d, base)) / diag
            haus = max(float(x.max()) for x in d) / diag
            print(json.dumps({"name": "closest_point", "method": name, **common, "build_s": round(b_s, 4),
                              "query_s": round(q_s, 4), "total_s": round(b_s + q_s, 4),
                              "max_diff_over_diag": err, "hausdorff_over_diag": round(haus, 6)}), flush=True)


if __name__ == "__main__":
    main()
