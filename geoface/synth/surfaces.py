"""Analytic test surfaces with known answers (areas, curvature, topology).

Every function returns ``(V, F)`` with outward / +Z-facing counter-clockwise faces.

>>> V, F = torus(1.0, 0.25, 32, 16)
>>> from geoface.mesh import topology_report
>>> topology_report(V, F).genus
1
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidMeshError
from ..mesh.core import face_areas, remove_unreferenced


def _check_int(name: str, value, minimum: int) -> int:
    if int(value) != value or value < minimum:
        raise InvalidMeshError(f"{name} must be an integer >= {minimum}; got {value!r}")
    return int(value)


def _grid_faces(nu: int, nv: int, wrap_u: bool = False, wrap_v: bool = False) -> np.ndarray:
    """Triangles of an ``nu x nv`` vertex grid (index ``i * nv + j``), optionally periodic."""
    iu = np.arange(nu if wrap_u else nu - 1)
    jv = np.arange(nv if wrap_v else nv - 1)
    I, J = np.meshgrid(iu, jv, indexing="ij")
    I, J = I.ravel(), J.ravel()
    I1, J1 = (I + 1) % nu, (J + 1) % nv
    a, b, c, d = I * nv + J, I1 * nv + J, I1 * nv + J1, I * nv + J1
    # alternate the diagonal in a checkerboard so the grid has no preferred direction
    alt = (I + J) % 2 == 1
    t1 = np.where(alt[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(alt[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)


def square_grid(n: int = 16, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat ``n x n`` vertex grid on ``[0, size]^2`` in the plane z = 0 (area ``size**2``)."""
    n = _check_int("n", n, 2)
    t = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(t, t, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], 1)
    return V, _grid_faces(n, n)


def _ring_stitch(counts: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Triangulate concentric rings (ring 0 may be a single centre vertex), vectorised.

    Ring ``k`` has ``counts[k]`` vertices at angles ``2*pi*(i + offsets[k]) / counts[k]``,
    numbered consecutively ring after ring.  Consecutive rings are zipped by merging
    their sorted angles; each merge event emits one triangle.
    """
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = []
    for k in range(len(counts) - 1):
        na, nb = int(counts[k]), int(counts[k + 1])
        sa, sb = int(starts[k]), int(starts[k + 1])
        if na == 1:
            j = np.arange(nb)
            tris.append(np.stack([np.full(nb, sa), sb + j, sb + (j + 1) % nb], 1))
            continue
        ang_a = (np.arange(na) + offsets[k]) / na
        ang_b = (np.arange(nb) + offsets[k + 1]) / nb
        # events: advancing along ring a (from vertex i to i+1) happens at the midpoint angle
        ev = np.concatenate([ang_a + 0.5 / na, ang_b + 0.5 / nb])
        is_a = np.concatenate([np.ones(na, bool), np.zeros(nb, bool)])
        order = np.argsort(ev, kind="stable")
        is_a = is_a[order]
        # state before each event: current index on each ring
        ca = np.concatenate([[0], np.cumsum(is_a)[:-1]])
        cb = np.concatenate([[0], np.cumsum(~is_a)[:-1]])
        # align the starting vertices: the vertex of ring b closest to angle of a[0]
        b0 = int(np.argmin(np.abs(((ang_b - ang_a[0]) + 0.5) % 1.0 - 0.5)))
        a_cur = sa + ca % na
        b_cur = sb + (b0 + cb) % nb
        a_nxt = sa + (ca + 1) % na
        b_nxt = sb + (b0 + cb + 1) % nb
        t = np.where(is_a[:, None], np.stack([a_cur, b_cur, a_nxt], 1), np.stack([a_cur, b_cur, b_nxt], 1))
        tris.append(t)
    F = np.concatenate(tris).astype(np.int64)
    return F


def _rings(n_rings: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ring counts (1, 6, 12, ...) and each vertex's (ring radius in [0,1], angle)."""
    counts = np.concatenate([[1], 6 * np.arange(1, n_rings + 1)])
    offsets = np.where(np.arange(len(counts)) % 2 == 0, 0.0, 0.5)
    k = np.repeat(np.arange(len(counts)), counts)
    idx = np.concatenate([np.arange(c) for c in counts])
    rho = k / n_rings
    theta = 2 * np.pi * (idx + offsets[k]) / counts[k]
    return counts, offsets, np.stack([rho, theta], 1)


def disk_grid(n_rings: int = 8, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat disk of concentric rings (1 + 3 n (n+1) vertices) in the plane z = 0."""
    n_rings = _check_int("n_rings", n_rings, 1)
    counts, offsets, rt = _rings(n_rings)
    V = np.stack([radius * rt[:, 0] * np.cos(rt[:, 1]), radius * rt[:, 0] * np.sin(rt[:, 1]), np.zeros(len(rt))], 1)
    F = _ring_stitch(counts, offsets)
    return V, _orient_up(V, F)


def _orient_up(V: np.ndarray, F: np.ndarray, axis: np.ndarray | None = None) -> np.ndarray:
    """Flip all faces if their mean normal points against ``axis`` (default +Z)."""
    axis = np.array([0.0, 0.0, 1.0]) if axis is None else axis
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return F if N.sum(0) @ axis >= 0 else F[:, ::-1].copy()


def irregular_flat_patch(n: int = 400, seed: int = 0, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat square patch with jittered, irregular interior vertices (Delaunay triangulated).

    Boundary vertices stay on the square's sides, so the area is exactly ``size**2``.
    """
    from scipy.spatial import Delaunay

    n = _check_int("n", n, 16)
    rng = np.random.default_rng(seed)
    k = max(int(np.sqrt(n)), 4)
    t = np.linspace(0, 1, k)
    X, Y = np.meshgrid(t, t, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel()], 1)
    interior = (P > 0).all(1) & (P < 1).all(1)
    h = 1.0 / (k - 1)
    P[interior] += rng.uniform(-0.35 * h, 0.35 * h, size=(int(interior.sum()), 2))
    tri = Delaunay(P)
    F = tri.simplices.astype(np.int64)
    V = np.concatenate([P * size, np.zeros((len(P), 1))], 1)
    A = face_areas(V, F)
    F = F[A > 1e-12 * size * size]
    return V, _orient_up(V, F)


def spherical_cap(radius: float = 1.0, angle: float = np.pi / 3, n_rings: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Cap of a sphere of ``radius`` around +Z, polar angle up to ``angle``.

    Exact area ``2*pi*R^2*(1 - cos(angle))``; total Gaussian curvature ``2*pi*(1 - cos(angle))``.
    """
    n_rings = _check_int("n_rings", n_rings, 1)
    if not (0 < angle < np.pi):
        raise InvalidMeshError(f"angle must be in (0, pi); got {angle!r}")
    counts, offsets, rt = _rings(n_rings)
    phi = rt[:, 0] * angle
    V = radius * np.stack([np.sin(phi) * np.cos(rt[:, 1]), np.sin(phi) * np.sin(rt[:, 1]), np.cos(phi)], 1)
    F = _ring_stitch(counts, offsets)
    return V, _orient_up(V, F)


def hemisphere(radius: float = 1.0, n_rings: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Upper hemisphere (z >= 0); area ``2*pi*R^2``."""
    return spherical_cap(radius, np.pi / 2, n_rings)


def sphere(radius: float = 1.0, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere with outward faces; closed, genus 0."""
    import trimesh

    subdivisions = _check_int("subdivisions", subdivisions, 0)
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def cylinder(radius: float = 1.0, height: float = 2.0, n_around: int = 32, n_high: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Open tube around the Z axis (two boundary loops); lateral area ``2*pi*r*h`` in the limit."""
    n_around = _check_int("n_around", n_around, 3)
    n_high = _check_int("n_high", n_high, 2)
    z = np.linspace(-height / 2, height / 2, n_high)
    th = 2 * np.pi * np.arange(n_around) / n_around
    T, Z = np.meshgrid(th, z, indexing="ij")
    V = np.stack([radius * np.cos(T).ravel(), radius * np.sin(T).ravel(), Z.ravel()], 1)
    F = _grid_faces(n_around, n_high, wrap_u=True)
    return V, _orient_outward(V, F)


def torus(R: float = 1.0, r: float = 0.3, n_u: int = 48, n_v: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Closed torus (genus 1) around the Z axis; exact area ``4*pi^2*R*r`` in the limit."""
    n_u = _check_int("n_u", n_u, 3)
    n_v = _check_int("n_v", n_v, 3)
    if not (0 < r < R):
        raise InvalidMeshError(f"need 0 < r < R; got R={R!r}, r={r!r}")
    u = 2 * np.pi * np.arange(n_u) / n_u
    v = 2 * np.pi * np.arange(n_v) / n_v
    U, W = np.meshgrid(u, v, indexing="ij")
    U, W = U.ravel(), W.ravel()
    V = np.stack([(R + r * np.cos(W)) * np.cos(U), (R + r * np.cos(W)) * np.sin(U), r * np.sin(W)], 1)
    F = _grid_faces(n_u, n_v, wrap_u=True, wrap_v=True)
    return V, _orient_outward(V, F)


def _orient_outward(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Flip all faces if they point inward on average (normals vs. offset from the axis/centroid)."""
    C = V[F].mean(1)
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    # radial direction from the z axis works for tubes and tori
    radial = C.copy()
    radial[:, 2] = 0.0
    if np.allclose(radial, 0):
        radial = C - V.mean(0)
    return F if np.einsum("ij,ij->", N, radial) >= 0 else F[:, ::-1].copy()


def genus2(resolution: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Closed genus-2 surface ("pretzel"): the level set
    ``(x (x-1)^2 (x-2) + y^2)^2 + z^2 = 0.01`` triangulated by marching cubes (scikit-image).

    Marching cubes leaves some near-degenerate triangles: a realistic input for repair.
    """
    from .._lazy import lazy_import

    measure = lazy_import("skimage.measure", "genus2")
    resolution = _check_int("resolution", resolution, 16)
    lo = np.array([-0.35, -1.0, -0.2])
    hi = np.array([2.35, 1.0, 0.2])
    ext = hi - lo
    h = ext[0] / resolution
    shape = np.maximum(np.ceil(ext / h).astype(int) + 1, 8)
    axes = [lo[i] + h * np.arange(shape[i]) for i in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    f = (X * (X - 1) ** 2 * (X - 2) + Y**2) ** 2 + Z**2 - 0.01
    verts, faces, _, _ = measure.marching_cubes(f, level=0.0, spacing=(h, h, h))
    V = verts + lo
    F = faces.astype(np.int64)
    V, F, _ = remove_unreferenced(V.astype(np.float64), F)
    # marching cubes on f (negative inside) winds faces towards increasing f: outward
    from ..mesh.core import signed_volume

    if signed_volume(V, F) < 0:
        F = F[:, ::-1].copy()
    return V, F


def mobius_strip(n_around: int = 48, n_across: int = 5, width: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """A Moebius strip: non-orientable, one boundary loop (for repair tests)."""
    n_around = _check_int("n_around", n_around, 6)
    n_across = _check_int("n_across", n_across, 2)
    u = 2 * np.pi * np.arange(n_around) / n_around
    s = np.linspace(-width / 2, width / 2, n_across)
    U, S = np.meshgrid(u, s, indexing="ij")
    U, S = U.ravel(), S.ravel()
    V = np.stack([(1 + S * np.cos(U / 2)) * np.cos(U), (1 + S * np.cos(U / 2)) * np.sin(U), S * np.sin(U / 2)], 1)
    F = _grid_faces(n_around, n_across)  # rows 0..n_around-1, not wrapped
    # close the strip with the half twist: last column joins the first with "across" reversed
    i = n_around - 1
    j = np.arange(n_across - 1)
    a, b = i * n_across + j, 0 * n_across + (n_across - 1 - j)
    c, d = 0 * n_across + (n_across - 2 - j), i * n_across + j + 1
    F = np.concatenate([F, np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return V, F


def punch_holes(V, F, n_holes: int = 3, radius: float = 0.05, seed: int = 0, avoid_boundary: bool = True):
    """Remove faces within ``radius * bbox_diagonal`` of ``n_holes`` random vertices.

    Returns ``(V, F_with_holes)``; vertices are kept (some become unreferenced), so
    vertex indices stay valid.  Used to test hole filling on procedural heads.
    """
    from ..mesh.core import bbox_diagonal, boundary_loops, check_mesh

    V, F = check_mesh(V, F)
    rng = np.random.default_rng(seed)
    diag = bbox_diagonal(V)
    r = radius * diag
    used = np.unique(F)
    candidates = used
    if avoid_boundary:
        loops = boundary_loops(F)
        if loops:
            bverts = np.concatenate(loops)
            from scipy.spatial import cKDTree

            d, _ = cKDTree(V[bverts]).query(V[used])
            candidates = used[d > 2.5 * r]
    if len(candidates) < n_holes:
        raise InvalidMeshError("mesh too small for the requested holes")
    centres = V[rng.choice(candidates, size=n_holes, replace=False)]
    C = V[F].mean(1)
    dist = np.min(np.linalg.norm(C[:, None, :] - centres[None], axis=2), axis=1)
    return V, F[dist > r]
