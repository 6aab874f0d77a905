"""Write a deliberately messy procedural head, as a real scan might arrive.

Holes punched in the face and scalp, near-duplicate vertices (a triangle soup in
places), a floating debris component and a non-manifold fin; with ``closed=True`` the
neck is capped too (a closed surface).  Used by ``make demo``, the tests and the repair
benchmark.

    python data_tools/make_messy_head.py OUT.ply [--vertices 20000] [--seed 0] [--closed]
"""

from __future__ import annotations

import argparse

import numpy as np


def messy_head(n_vertices: int = 20000, seed: int = 0, closed: bool = False):
    from geoface.mesh.core import boundary_loops
    from geoface.synth import procedural_head, punch_holes

    rng = np.random.default_rng(seed)
    head = procedural_head(n_vertices=n_vertices, seed=seed)
    V, F = head.V, head.F
    if closed:  # cap the neck with a fan: the surface becomes closed
        loop = boundary_loops(F)[0]
        c = len(V)
        V = np.concatenate([V, V[loop].mean(0, keepdims=True)])
        F = np.concatenate([F, np.stack([np.roll(loop, -1), loop, np.full(len(loop), c)], 1)])
    # holes
    V, F = punch_holes(V, F, n_holes=4, radius=0.03, seed=seed)
    # unweld 5% of the faces into a soup (exact duplicate vertices)
    soup = rng.random(len(F)) < 0.05
    k = int(soup.sum())
    newV = V[F[soup].ravel()]
    # jitter far below the merge tolerance, so the loader's exact weld does not catch them
    newV = newV + 1e-9 * rng.standard_normal(newV.shape)
    F = F.copy()
    F[soup] = len(V) + np.arange(3 * k).reshape(k, 3)
    V = np.concatenate([V, newV])
    # a floating debris triangle cluster and a non-manifold fin on an existing edge
    debris = V.mean(0) + np.array([0.3, 0.0, 0.0]) + 0.01 * rng.standard_normal((4, 3))
    F = np.concatenate([F, len(V) + np.array([[0, 1, 2], [0, 2, 3]])])
    V = np.concatenate([V, debris])
    a, b = F[0, 0], F[0, 1]
    fin = (V[a] + V[b]) / 2 + np.array([0.0, 0.0, 0.02])
    F = np.concatenate([F, [[a, b, len(V)]]])
    V = np.concatenate([V, fin[None]])
    return V, F


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("output")
    ap.add_argument("--vertices", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--closed", action="store_true", help="cap the neck (a closed surface)")
    args = ap.parse_args()
    from geoface.mesh.io import save_mesh

    V, F = messy_head(args.vertices, args.seed, args.closed)
    save_mesh(args.output, V=V, F=F)
    print(f"wrote {args.output}: {len(V)} vertices, {len(F)} faces (messy on purpose)")


if __name__ == "__main__":
    main()
