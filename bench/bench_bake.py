"""Time closest-point baking and push-pull inpainting; one JSON line per case.

    python bench/bench_bake.py [--quick]

Cases: bake a 512² geometry image of a coarse hemisphere from per-vertex-coloured spheres of
~1e5 (icosphere, 4^7·10+2 vertices) and ~1e6 (latitude–longitude) vertices: seconds for the AABB
build + closest-point queries (``query_s``, libigl ``point_mesh_squared_distance``), the same split
into build / query with a reusable ``igl.AABB`` tree, and the whole ``bake_gimage`` call; colour
error against the analytic colour.  Then push-pull inpainting of a 1024² RGB image with half its
texels missing (random holes) and with one big hole.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from geoface.gimage import geometry_image
from geoface.mesh.io import Mesh
from geoface.synth import sphere, spherical_cap
from geoface.uvmap import bake_gimage, closest_points, inpaint


def latlong_sphere(n_rings: int, n_around: int):
    """Closed UV sphere: ``n_rings`` interior latitude rings × ``n_around`` + two poles."""
    th = np.linspace(0, np.pi, n_rings + 2)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    V = np.vstack([V, [[0, 0, 1.0], [0, 0, -1.0]]])
    i, j = np.meshgrid(np.arange(n_rings - 1), np.arange(n_around), indexing="ij")
    a, b = i * n_around + j, i * n_around + (j + 1) % n_around
    c, d = a + n_around, b + n_around
    quads = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    top, bot = len(V) - 2, len(V) - 1
    j = np.arange(n_around)
    last = (n_rings - 1) * n_around
    caps = np.concatenate([np.stack([np.full(n_around, top), j, (j + 1) % n_around], 1),
                           np.stack([np.full(n_around, bot), last + (j + 1) % n_around, last + j], 1)])
    return V, np.concatenate([quads, caps]).astype(np.int64)


def color(P):
    return 0.5 + 0.4 * np.sin(3.0 * P)


def bake_case(name, V, F, N):
    igl = __import__("igl")
    src = Mesh(V, F, colors=color(V))
    Vt, Ft = spherical_cap(1.0, np.pi / 2 * 0.98, n_rings=40)
    gi = geometry_image(Vt, Ft, Vt[:, :2] / 2 + 0.5, N)
    P = gi.positions()[gi.mask]
    t0 = time.perf_counter()
    closest_points(P, V, F)
    q = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree = igl.AABB()
    tree.init(V, F)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree.squared_distance(V, F, P)
    query_only = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = bake_gimage(gi, src)
    total = time.perf_counter() - t0
    got = out.modality("texture").transpose(1, 2, 0)[out.mask]
    Pm = out.positions()[out.mask]
    err = np.abs(got - color(Pm / np.linalg.norm(Pm, axis=1, keepdims=True))).max()
    print(json.dumps({"case": name, "source_vertices": len(V), "source_faces": len(F), "N": N,
                      "queries": int(len(P)), "query_s": round(q, 3), "aabb_build_s": round(build, 3),
                      "aabb_query_s": round(query_only, 3), "bake_total_s": round(total, 3),
                      "max_color_err": float(err)}), flush=True)


def inpaint_case(name, N, mask):
    rng = np.random.default_rng(0)
    img = rng.random((N, N, 3)).astype(np.float32)
    t0 = time.perf_counter()
    out = inpaint(img, mask)
    s = time.perf_counter() - t0
    assert np.array_equal(out[mask], img[mask]) and np.isfinite(out).all()
    print(json.dumps({"case": name, "size": N, "missing": float(1 - mask.mean()), "seconds": round(s, 3)}), flush=True)


def main(quick: bool = False) -> None:
    N = 128 if quick else 512
    V, F = sphere(1.0, 4 if quick else 7)
    bake_case("bake_gimage/icosphere", V, F, N)
    V, F = latlong_sphere(70, 140) if quick else latlong_sphere(707, 1414)
    bake_case("bake_gimage/latlong_sphere", V, F, N)
    S = 256 if quick else 1024
    rng = np.random.default_rng(1)
    inpaint_case("inpaint/pushpull_random_half", S, rng.random((S, S)) > 0.5)
    m = np.ones((S, S), bool)
    m[S // 4: 3 * S // 4, S // 4: 3 * S // 4] = False
    inpaint_case("inpaint/pushpull_big_hole", S, m)


if __name__ == "__main__":
    main("--quick" in sys.argv)
