"""A surface from a point cloud: a scan that was never meshed (a depth sensor, photogrammetry
points) becomes a triangle mesh that the rest of the pipeline repairs and maps.

Screened Poisson reconstruction (Kazhdan & Hoppe 2013, MeshLab's implementation through
pymeshlab): normals are estimated where the file has none (PCA over ``k`` neighbours, oriented
consistently, then outwards as a whole), the implicit surface is solved on an octree of
``depth`` levels and its zero set extracted; then everything Poisson invented far from the
points is trimmed away — the cap it puts over an open scan's back, the skin it stretches over
a hole — so that an open face scan stays open and the repair decides what to fill.

>>> import numpy as np
>>> from geoface.synth import sphere
>>> V, F = sphere(20)
>>> S = surface_from_points(V)
>>> bool(len(S.F) > 0), S.normals_estimated
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InvalidMeshError, MeshFormatError
from ..progress import log

__all__ = ["PointSurface", "surface_from_points", "load_points"]


@dataclass(frozen=True)
class PointSurface:
    """A surface reconstructed from points: ``V``, ``F``, how many of Poisson's faces were
    trimmed as too far from any point, and whether the normals were estimated."""
    V: np.ndarray
    F: np.ndarray
    points: int
    depth: int
    trimmed_faces: int
    normals_estimated: bool
    pieces_dropped: int = 0

    def summary(self) -> str:
        how = "normals estimated" if self.normals_estimated else "the file's normals"
        return (f"{self.points} points -> {len(self.V)} vertices, {len(self.F)} faces (screened Poisson, depth "
                f"{self.depth}, {how}; {self.trimmed_faces} faces far from the points trimmed, "
                f"{self.pieces_dropped} small pieces dropped)")


def _spacing(P: np.ndarray, tree) -> float:
    """Median distance from a point to its nearest neighbour (on a sample of the points)."""
    rng = np.random.default_rng(0)
    sample = P if len(P) <= 20000 else P[rng.choice(len(P), 20000, replace=False)]
    d, _ = tree.query(sample, k=2)
    return float(np.median(d[:, 1]))


def surface_from_points(P, normals=None, *, depth: int | None = None, k: int = 12, trim: float = 3.0,
                        quiet: bool | None = None) -> PointSurface:
    """Reconstruct a triangle surface from points ``P (n, 3)`` (with or without ``normals``).

    Parameters
    ----------
    P : (n, 3) float, n >= 20
    normals : (n, 3) float or None; estimated from ``k`` neighbours when None (or unusable)
    depth : octree depth of the Poisson solve (None: 8 up to 20K points, 9 up to 500K, else 10;
        each level halves the smallest detail kept)
    trim : faces whose corners all lie farther than ``trim`` times the points' median spacing
        from every point are removed (Poisson's closure of open scans and holes); the surface
        may reach about that far past a scan's edge
    """
    import pymeshlab
    from scipy.spatial import cKDTree

    P = np.asarray(P, np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidMeshError(f"points must be an (n, 3) array; got shape {P.shape}")
    bad = ~np.isfinite(P).all(1)
    if bad.any():
        raise InvalidMeshError(f"{int(bad.sum())} of {len(P)} points have coordinates that are not finite "
                               f"(the first: point {int(np.flatnonzero(bad)[0])})")
    if len(np.unique(P, axis=0)) < 20:
        raise InvalidMeshError(f"a point cloud needs at least 20 distinct points for a surface; got {len(np.unique(P, axis=0))}")
    sv = np.linalg.svd(P - P.mean(0), compute_uv=False)
    if sv[1] <= 1e-9 * sv[0]:
        raise InvalidMeshError(f"the {len(P)} points lie on a line: no surface")
    if sv[2] <= 1e-9 * sv[0]:
        raise InvalidMeshError(f"the {len(P)} points lie in a plane: no surface with an inside")
    N = None
    if normals is not None:
        N = np.asarray(normals, np.float64)
        if N.shape != P.shape:
            raise InvalidMeshError(f"normals must be an array like the points, {P.shape}; got {N.shape}")
        if not np.isfinite(N).all():
            raise InvalidMeshError(f"{int((~np.isfinite(N).all(1)).sum())} of {len(P)} normals are not finite")
        length = np.linalg.norm(N, axis=1)
        if (length < 1e-12).mean() > 0.01:
            N = None  # unusable normals: estimate them
        else:
            N = N / np.maximum(length, 1e-12)[:, None]
    if depth is None:
        depth = 8 if len(P) <= 20_000 else 9 if len(P) <= 500_000 else 10
    ms = pymeshlab.MeshSet()
    if N is None:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=P))
        ms.compute_normal_for_point_clouds(k=int(k), smoothiter=1)
        N = ms.current_mesh().vertex_normal_matrix()
        # outwards as a whole: most normals point away from the centroid on a scan of a head
        if np.mean(np.einsum("ij,ij->i", N, P - P.mean(0))) < 0:
            N = -N
        ms = pymeshlab.MeshSet()
        estimated = True
    else:
        estimated = False
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=P, v_normals_matrix=N))
    log(f"points: screened Poisson on {len(P)} points (depth {depth})", quiet=quiet)
    ms.generate_surface_reconstruction_screened_poisson(depth=int(depth), preclean=True, threads=2)
    ms.meshing_remove_duplicate_vertices()  # marching cubes repeats a vertex where cells meet
    ms.meshing_remove_null_faces()
    m = ms.current_mesh()
    V, F = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    if len(F) == 0:
        raise InvalidMeshError("screened Poisson found no surface in these points (are they all on a line or a plane?)")
    tree = cKDTree(P)
    far = tree.query(V)[0] > trim * _spacing(P, tree)
    drop = far[F].all(1)  # (a stricter rule tears small holes and pinches into real surface)
    F = F[~drop]
    # one object: the largest piece (the rest are Poisson's islands around stray points)
    from ..mesh import face_components

    pieces, comp = face_components(F, len(V))
    if pieces > 1:
        F = F[comp == np.argmax(np.bincount(comp))]
    used = np.unique(F)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    if len(F) == 0:
        raise InvalidMeshError("nothing of the Poisson surface lies near the points")
    return PointSurface(V, F, points=len(P), depth=int(depth), trimmed_faces=int(drop.sum()), normals_estimated=estimated,
                        pieces_dropped=max(pieces - 1, 0))


def load_points(path) -> tuple[np.ndarray, np.ndarray | None]:
    """The points (and normals, when the file has them) of a point-cloud file: a PLY, OBJ or
    OFF with vertices and no faces, or an ``.xyz``/``.txt`` of ``x y z [nx ny nz]`` rows."""
    path = Path(path)
    if not path.is_file():
        raise MeshFormatError(f"no such file: {path}")
    if path.suffix.lower() in (".xyz", ".txt", ".pts"):
        try:
            a = np.loadtxt(path, ndmin=2, comments="#")
        except ValueError as e:
            raise MeshFormatError(f"{path.name}: not rows of numbers ({e})") from None
        if a.shape[1] not in (3, 6):
            raise MeshFormatError(f"{path.name}: rows of 3 (x y z) or 6 (x y z nx ny nz) numbers expected; got {a.shape[1]}")
        return a[:, :3], (a[:, 3:6] if a.shape[1] == 6 else None)
    if path.suffix.lower() in (".obj", ".off"):
        text_cloud = _text_cloud(path)
        if text_cloud is not None:
            return text_cloud
    import trimesh

    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as e:  # noqa: BLE001 — trimesh raises many kinds for corrupt input
        raise MeshFormatError(f"cannot read {path.name}: {type(e).__name__}: {e}") from None
    P = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), np.float64)
    if len(P) == 0:
        raise MeshFormatError(f"{path.name} holds no points")
    normals = None
    raw = getattr(loaded, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    # a binary PLY's vertex columns are a structured array, an ASCII PLY's a dict of arrays
    names = () if raw is None else (tuple(raw.keys()) if isinstance(raw, dict) else (raw.dtype.names or ()))
    if all(c in names for c in ("nx", "ny", "nz")):
        normals = np.column_stack([np.asarray(raw[c], np.float64).ravel() for c in ("nx", "ny", "nz")])
        if normals.shape != P.shape:
            normals = None
    return P, normals


def _text_cloud(path: Path):
    """``(points, normals or None)`` of an OBJ or OFF point cloud with its normals: an OBJ whose
    ``vn`` lines are as many as its ``v`` lines (a point cloud's exporters write them in step),
    a ``NOFF`` (or ``CNOFF``) whose rows carry them; None where the file has no normals (trimesh
    reads it) or faces."""
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise MeshFormatError(f"cannot read {path.name}: {e}") from None
    rows = [ln.split("#", 1)[0].split() for ln in text.splitlines()]
    rows = [r for r in rows if r]
    try:
        if path.suffix.lower() == ".obj":
            if any(r[0] == "f" for r in rows):
                return None
            v = [r[1:4] for r in rows if r[0] == "v"]
            vn = [r[1:4] for r in rows if r[0] == "vn"]
            if not v or len(vn) != len(v):
                return None
            return np.array(v, np.float64), np.array(vn, np.float64)
        head = rows[0][0] if rows else ""
        if not head.endswith("OFF") or "N" not in head.replace("OFF", "") or len(rows) < 2:
            return None
        nv, nf = int(rows[1][0]), int(rows[1][1])
        if nf:
            return None
        A = np.array([r[:6] for r in rows[2:2 + nv]], np.float64)
        if A.shape != (nv, 6):
            raise ValueError(f"{nv} rows of x y z nx ny nz expected")
        return A[:, :3], A[:, 3:6]
    except (ValueError, IndexError) as e:
        raise MeshFormatError(f"cannot read {path.name} as a point cloud: {e}") from None
