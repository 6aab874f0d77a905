"""Stress cases for ``geoface convert``: real meshes and ICT-FaceKit heads made hostile the way
scans from other people arrive.

Every case is a mesh together with what is known about it: the rigid motion (rotation ``R``,
scale ``s``, offset ``t``: ``x_case = s R x_base + t``) that took it from its base mesh, the
base's up and front in the case's coordinates, and for human heads the 3D positions of the
nose tip, the two eyes' centres and the chin (ICT-FaceKit's Multi-PIE landmarks, or marked by
hand on the real heads), so a test can look where they land in the images.

Kinds of case (``CASE_KINDS``):

* ``axes``: the base in another axis convention (``CONVENTIONS``): Z-up facing +X (scanning and
  acoustics software), Z-up facing −Y (Blender), X-up (lying on its side), upside down, ...,
  and one tilted 35° off every axis, in millimetres, 10 m from the origin;
* ``fins``: double-sided triangles hanging off edges (a triangle and its reverse, both ways);
* ``debris``: tiny floating components (closed and open, near and far);
* ``soup``: an OBJ whose every corner has its own normal (``f a//na b//nb c//nc``), read as a
  triangle soup by a loader that keeps corners apart (written to disk; see :func:`write_soup_obj`);
* ``holes``: 18 small holes;
* ``slivers``: narrow strips of needle triangles (edges split a thousandth from their ends);
* ``face_only``: an ICT face cut to its face mask (an open face scan, no back of the head);
* ``closed_neck``: an ICT head closed at the neck by a flat cap (a closed head), its eye and
  mouth openings filled;
* ``decimated``: coarse, 1K faces (quadric decimation);
* ``photo``: an ICT head open at the neck with 18 holes and 3 floating components (a 3D photo);
* ``raw_face``: an ICT face, subdivided to ~47K vertices, with fins and 5 floating components;
* ``turned``: the base (and its face-only and closed variants) turned by a random rotation (not an
  axis permutation: ``turned(base, seed)``);
* ``torso``: an ICT head on shoulders in a shirt: the head closed at the neck, joined (a boolean
  union, manifold3d) to a torso with a collar, one closed surface (a head-and-shoulders 3D photo);
* ``plinth``: an ICT head closed at the neck standing on a flat square plinth (a bust on its base).

    python data_tools/make_stress_cases.py OUT_DIR [--ict 2] [--meshes face.obj lion.off] [--kinds axes fins]

writes ``OUT_DIR/<case>.obj`` (or ``.ply``) and ``OUT_DIR/cases.json`` (one entry a case: its
file, base, kind, convention, ``R``/``s``/``t``, up, front, landmarks).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

#: axis conventions: the file's (up, front) axes of the head
CONVENTIONS = {
    "y-up": ((0, 1, 0), (0, 0, 1)),
    "z-up+x": ((0, 0, 1), (1, 0, 0)),
    "z-up-y": ((0, 0, 1), (0, -1, 0)),
    "x-up": ((1, 0, 0), (0, 0, -1)),
    "-x-up": ((-1, 0, 0), (0, 1, 0)),
    "-y-up": ((0, -1, 0), (0, 0, 1)),
    "-z-up": ((0, 0, -1), (0, 1, 0)),
    "y-up-x": ((0, 1, 0), (-1, 0, 0)),
}
#: the tilted case: up and front 35° off every axis, millimetres, far from the origin
TILTED = "tilted-mm-far"

CASE_KINDS = ("axes", "fins", "debris", "soup", "holes", "slivers", "face_only", "closed_neck", "decimated", "photo",
              "raw_face", "turned", "torso", "plinth")

#: the real meshes of ../shared/data/meshes (also vendored in tests/data/meshes): up and front
#: as modelled (all are Y-up), and for the human heads the nose tip, eyes and chin marked by hand
#: (nearest vertex to these points, in the file's units)
REAL = {
    "face.obj": {"up": (0, 1, 0), "front": (0, 0, 1), "head": True},
    "ninjaHead_Low.obj": {"up": (0, 1, 0), "front": (0, 0, 1), "head": True},
    "decimated-max.obj": {"up": (0, 1, 0), "front": (0, 0, -1), "head": True},
    "camelhead.off": {"up": (0, 1, 0), "front": (0, 0, 1), "head": False},
    "lion.off": {"up": (0, 1, 0), "front": (0, 0, -1), "head": False},
    "spot.obj": {"up": (0, 1, 0), "front": (0, 0, -1), "head": False},
    "beetle.obj": {"up": (0, 1, 0), "front": (0, 0, 1), "head": False},
    "male02.obj": {"up": (0, 1, 0), "front": (0, 0, 1), "head": False},
    "female02.obj": {"up": (0, 1, 0), "front": (0, 0, 1), "head": False},
}


@dataclass
class StressCase:
    """A stress case: ``V``, ``F`` (``faces_file``: how it must be written, e.g. the soup OBJ),
    the motion from its base, up/front, and the landmarks (``{name: (3,)}``) of a human head."""

    name: str
    base: str
    kind: str
    V: np.ndarray
    F: np.ndarray
    convention: str = "y-up"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    s: float = 1.0
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    front: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    landmarks: dict = field(default_factory=dict)
    roi: np.ndarray | None = None  # a face mask over V, where the base has one (ICT)
    soup: bool = False

    def to_json(self, file: str) -> dict:
        return {"name": self.name, "file": file, "base": self.base, "kind": self.kind, "convention": self.convention,
                "R": self.R.tolist(), "s": self.s, "t": self.t.tolist(), "up": self.up.tolist(), "front": self.front.tolist(),
                "landmarks": {k: np.asarray(v).tolist() for k, v in self.landmarks.items()}}

    def save(self, folder: Path) -> str:
        from geoface.mesh.io import save_mesh

        folder.mkdir(parents=True, exist_ok=True)
        name = f"{self.name}.obj"
        if self.soup:
            write_soup_obj(folder / name, self.V, self.F)
        else:
            save_mesh(folder / name, V=self.V, F=self.F, overwrite=True)
        return name


def rotation(up_from, front_from, up_to, front_to) -> np.ndarray:
    """The rotation taking the frame (up_from, front_from) to (up_to, front_to)."""

    def frame(u, f):
        u = np.asarray(u, float) / np.linalg.norm(u)
        f = np.asarray(f, float) - (np.asarray(f, float) @ u) * u
        f /= np.linalg.norm(f)
        return np.column_stack([u, f, np.cross(u, f)])

    return frame(up_to, front_to) @ frame(up_from, front_from).T


def _tilted() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", [35, -35, 35], degrees=True).as_matrix()


# ----------------------------------------------------------------------------------- bases
def ict_base(seed: int) -> StressCase:
    """An ICT-FaceKit head (identity N(0, 1) from ``seed``, three random expressions), Y-up
    facing +Z, in cm, with its face mask and landmarks."""
    from geoface.synth.ict import ict_head, load_ict_model, random_expression

    model = load_ict_model()
    rng = np.random.default_rng(seed)
    h = ict_head(model, seed=seed, expression=random_expression(rng, model.expression_names))
    return StressCase(f"ict{seed}", f"ict{seed}", "base", h.V.copy(), h.F.copy(), landmarks=ict_landmarks(h.V, h.landmarks),
                      roi=h.face_mask.copy())


def ict_landmarks(V: np.ndarray, lm: np.ndarray) -> dict:
    """Nose tip, the eyes (the subject's right and left: the midpoints of each eye's corners, which
    a blink does not move) and the chin from the 68 Multi-PIE landmarks (0-based: 30 nose tip, 36
    and 39 the right eye's corners, 42 and 45 the left's, 8 chin)."""
    return {"nose": V[lm[30]].copy(), "eye_right": V[lm[[36, 39]]].mean(0), "eye_left": V[lm[[42, 45]]].mean(0),
            "chin": V[lm[8]].copy()}


def real_base(name: str, folder: Path | None = None) -> StressCase:
    """A real mesh of ``../shared/data/meshes`` (or ``tests/data/meshes``) as loaded."""
    from geoface.mesh.io import load_mesh

    folder = folder or _mesh_folder()
    m = load_mesh(folder / name)
    info = REAL[name]
    c = StressCase(Path(name).stem, Path(name).stem, "base", m.V.copy(), m.F.copy(), up=np.array(info["up"], float),
                   front=np.array(info["front"], float))
    if info["head"]:
        c.landmarks = _marked_landmarks(name, m.V, m.F, info["front"])
    return c


#: landmarks marked by hand on the real human heads, from front views: (x, y) in the file's
#: units; the landmark is the front-facing vertex nearest to that point seen from the front
MARKED = {
    "face.obj": {"nose": (0.0, 166.3), "eye_right": (-3.3, 170.5), "eye_left": (3.3, 170.5), "chin": (0.0, 159.2)},
    "ninjaHead_Low.obj": {"nose": (0.0, 173.5), "eye_right": (-3.2, 179.0), "eye_left": (3.2, 179.0), "chin": (0.0, 167.5)},
    "decimated-max.obj": {"nose": (26.0, -14.0), "eye_right": (65.0, 30.0), "eye_left": (-5.0, 30.0), "chin": (27.0, -95.0)},
}


def _marked_landmarks(name: str, V: np.ndarray, F: np.ndarray, front) -> dict:
    from scipy.spatial import cKDTree

    fz = float(np.sign(front[2]))
    vn = _normals(V, F)
    cand = np.flatnonzero((vn[:, 2] * fz > 0.2) & (V[:, 2] * fz > np.median(V[:, 2] * fz)))
    tree = cKDTree(V[cand, :2])
    return {k: V[cand[tree.query(np.asarray(p, float))[1]]].copy() for k, p in MARKED.get(name, {}).items()}


def _mesh_folder() -> Path:
    for p in (REPO.parent / "shared" / "data" / "meshes", REPO / "tests" / "data" / "meshes"):
        if p.is_dir():
            return p
    raise FileNotFoundError("no mesh folder: ../shared/data/meshes or tests/data/meshes")


# ----------------------------------------------------------------------------------- moves
def moved(base: StressCase, convention: str) -> StressCase:
    """``base`` in another axis convention (``CONVENTIONS`` or ``TILTED``)."""
    s, t = 1.0, np.zeros(3)
    if convention == TILTED:
        R = _tilted() @ rotation(base.up, base.front, (0, 1, 0), (0, 0, 1))
        ext = float(np.ptp(base.V, 0).max())
        s = 10.0  # cm -> mm (most bases are in cm or unitless)
        t = np.array([1.0, -0.7, 0.4]) * 1000.0 * ext
    else:
        up, front = CONVENTIONS[convention]
        R = rotation(base.up, base.front, up, front)
    V = s * base.V @ R.T + t
    c = StressCase(f"{base.name}_{convention}", base.base, "axes", V, base.F.copy(), convention=convention, R=R @ base.R,
                   s=s * base.s, t=s * R @ base.t + t, up=R @ base.up, front=R @ base.front,
                   landmarks={k: s * R @ v + t for k, v in base.landmarks.items()}, roi=base.roi)
    return c


def turned(base: StressCase, seed: int) -> StressCase:
    """``base`` turned by a random rotation (uniform on SO(3), from ``seed``) about its centre."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=seed).as_matrix()
    c = 0.5 * (base.V.min(0) + base.V.max(0))
    t = c - R @ c
    return StressCase(f"{base.name}_turned{seed}", base.base, "turned", base.V @ R.T + t, base.F.copy(),
                      convention=f"turned{seed}", R=R @ base.R, s=base.s, t=R @ base.t + t, up=R @ base.up,
                      front=R @ base.front, landmarks={k: R @ v + t for k, v in base.landmarks.items()}, roi=base.roi)


def _manifold(V, F):
    import manifold3d as m3

    return m3.Manifold(m3.Mesh(vert_properties=np.asarray(V, np.float32), tri_verts=np.asarray(F, np.uint32)))


def _union(base: StressCase, kind: str, parts) -> StressCase:
    """The closed base joined to ``parts`` (manifold3d solids) by a boolean union: one closed surface."""
    from scipy.spatial import cKDTree

    head = closed_neck(base)
    solid = _manifold(head.V, head.F)
    for p in parts:
        solid = solid + p
    m = solid.to_mesh()
    V, F = np.asarray(m.vert_properties, float)[:, :3], np.asarray(m.tri_verts, np.int64)
    roi = None
    if base.roi is not None:  # the face mask: vertices at the head's face vertices
        d, i = cKDTree(base.V).query(V)
        roi = base.roi[i] & (d < 1e-3 * float(np.linalg.norm(np.ptp(base.V, 0))))
    return _derived(base, kind, V, F, roi=roi)


def _below_neck(base: StressCase):
    """The transform (3 x 4, columns: the base's right, up, front and the neck's centre) that puts
    a solid built along +x right, +y up, +z front under the neck of a base open at the neck, and
    the head's width."""
    from geoface.mesh.core import boundary_loops, loop_length

    loop = max(boundary_loops(base.F), key=lambda lp: loop_length(base.V, lp))  # the neck: the longest opening
    up, front = base.up / np.linalg.norm(base.up), base.front / np.linalg.norm(base.front)
    right = np.cross(up, front)
    c = base.V[loop].mean(0)
    low = float((base.V[loop] @ up).min())
    c = c + (low - c @ up) * up  # at the lowest point of the neck's cut
    return np.column_stack([right, up, front, c]).tolist(), float(np.ptp(base.V @ right))


#: a solid built along +z turned to stand along +y (a proper rotation: x stays, z -> y, y -> -z)
_Z_TO_Y = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]


def with_torso(base: StressCase) -> StressCase:
    """A head on shoulders in a shirt: the head closed at the neck, joined to a torso (an
    elliptic cone 2.4 head widths across at the shoulders, narrowing upwards) and a collar ring
    round the neck."""
    import manifold3d as m3

    M, w = _below_neck(base)
    r = 0.5 * w
    torso = m3.Manifold.cylinder(1.6 * r, 1.0 * r, 0.45 * r, 48).scale([2.4, 1.1, 1.0]).transform(_Z_TO_Y)
    torso = torso.translate([0.0, -1.4 * r, -0.1 * r])  # its top 0.2 r above the neck's lowest point
    collar = m3.Manifold.cylinder(0.3 * r, 0.5 * r, 0.42 * r, 48).transform(_Z_TO_Y).translate([0.0, 0.05 * r, 0.0])
    return _union(base, "torso", [torso.transform(M), collar.transform(M)])


def with_plinth(base: StressCase) -> StressCase:
    """A bust on its base: the head closed at the neck, standing on a flat square plinth."""
    import manifold3d as m3

    M, w = _below_neck(base)
    r = 0.5 * w
    neck = m3.Manifold.cylinder(0.9 * r, 0.42 * r, 0.42 * r, 32).transform(_Z_TO_Y).translate([0.0, -0.7 * r, 0.0])
    block = m3.Manifold.cube([1.8 * r, 0.4 * r, 1.8 * r], center=True).translate([0.0, -0.9 * r, 0.0])
    return _union(base, "plinth", [neck.transform(M), block.transform(M)])


def _derived(base: StressCase, kind: str, V, F, roi=None, **kw) -> StressCase:
    return StressCase(f"{base.name}_{kind}", base.base, kind, np.asarray(V, float), np.asarray(F, np.int64),
                      convention=base.convention, R=base.R, s=base.s, t=base.t, up=base.up, front=base.front,
                      landmarks=dict(base.landmarks), roi=roi, **kw)


def _normals(V, F):
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    vn = np.zeros_like(V)
    for k in range(3):
        np.add.at(vn, F[:, k], n)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)


def with_fins(base: StressCase, count: int = 12, seed: int = 0) -> StressCase:
    """Double-sided fins: on ``count`` random edges a new vertex above the edge and the two
    triangles (a, b, c) and (b, a, c) — a sheet with both orientations, non-manifold."""
    rng = np.random.default_rng(seed)
    V, F = base.V.copy(), base.F.copy()
    vn = _normals(V, F)
    diag = float(np.linalg.norm(np.ptp(V, 0)))
    faces = rng.choice(len(F), size=count, replace=False)
    newV, newF = [], []
    for f in faces:
        a, b = int(F[f, 0]), int(F[f, 1])
        c = len(V) + len(newV)
        newV.append(0.5 * (V[a] + V[b]) + 0.02 * diag * (vn[a] + vn[b]) / 2)
        newF += [(a, b, c), (b, a, c)]
    return _derived(base, "fins", np.vstack([V, newV]), np.vstack([F, newF]), roi=_pad(base.roi, len(newV)))


def _pad(roi, k):
    return None if roi is None else np.concatenate([roi, np.zeros(k, bool)])


def _debris_pieces(V, count, rng, scale=0.01):
    """``count`` tiny components: tetrahedra (closed) and single triangles (open), near the
    surface and far from it."""
    diag = float(np.linalg.norm(np.ptp(V, 0)))
    lo, hi = V.min(0), V.max(0)
    P, T = [], []
    n0 = len(V)
    for i in range(count):
        far = i % 3 == 2
        c = lo + rng.random(3) * (hi - lo) + (0.8 * diag * rng.standard_normal(3) if far else 0)
        r = scale * diag * (0.5 + rng.random())
        k = n0 + len(P)
        if i % 2 == 0:  # a closed tetrahedron
            P += list(c + r * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float))
            T += [(k, k + 1, k + 2), (k, k + 3, k + 1), (k, k + 2, k + 3), (k + 1, k + 3, k + 2)]
        else:  # an open triangle
            P += list(c + r * rng.standard_normal((3, 3)))
            T += [(k, k + 1, k + 2)]
    return np.array(P), np.array(T, np.int64)


def with_debris(base: StressCase, count: int = 6, seed: int = 0) -> StressCase:
    rng = np.random.default_rng(seed)
    P, T = _debris_pieces(base.V, count, rng)
    return _derived(base, "debris", np.vstack([base.V, P]), np.vstack([base.F, T]), roi=_pad(base.roi, len(P)))


def with_holes(base: StressCase, count: int = 18, seed: int = 0) -> StressCase:
    from geoface.synth import punch_holes

    V, F = punch_holes(base.V, base.F, n_holes=count, radius=0.012, seed=seed)
    return _derived(base, "holes", V, F, roi=base.roi)


def with_slivers(base: StressCase, strips: int = 3, seed: int = 0) -> StressCase:
    """Narrow strips of needle triangles: along ``strips`` shortest edge paths between random
    vertices, every edge of the faces the path runs through is split a thousandth of its
    length from one end (each split triangle gets a needle)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    from geoface.mesh.core import edge_topology

    rng = np.random.default_rng(seed)
    V, F = base.V.copy(), base.F.copy()
    et = edge_topology(F)
    E = et.E
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
    used = np.unique(F)
    path_vertices: set = set()
    for _ in range(strips):
        a, b = rng.choice(used, 2, replace=False)
        _, pred = dijkstra(G, directed=False, indices=int(a), return_predecessors=True)
        v = int(b)
        while v >= 0 and v != a:
            path_vertices.add(v)
            v = int(pred[v])
    strip = np.flatnonzero(np.isin(F, list(path_vertices)).any(1))
    # split each edge (a, b) of the strip's faces at a + 0.001 (b - a): one new vertex per edge
    newV: list = []
    mid: dict = {}
    out = [f for i, f in enumerate(F.tolist()) if i not in set(strip.tolist())]
    for f in F[strip].tolist():
        m = []
        for k in range(3):
            a, b = f[k], f[(k + 1) % 3]
            key = (min(a, b), max(a, b))
            if key not in mid:
                mid[key] = len(V) + len(newV)
                newV.append(V[key[0]] + 0.001 * (V[key[1]] - V[key[0]]))
            m.append(mid[key])
        a, b, c = f
        out += [[a, m[0], m[2]], [m[0], b, m[1]], [m[2], m[1], c], [m[0], m[1], m[2]]]
    # faces outside the strip that share a split edge keep it unsplit: split them too (a T-junction would crack)
    out = np.array(out, np.int64)
    fixed = []
    for f in out.tolist():
        mids = [mid.get((min(f[k], f[(k + 1) % 3]), max(f[k], f[(k + 1) % 3]))) for k in range(3)]
        if not any(x is not None for x in mids):
            fixed.append(f)
            continue
        fixed += _split_face(f, mids)
    V2 = np.vstack([V, newV])
    return _derived(base, "slivers", V2, np.array(fixed, np.int64), roi=_pad(base.roi, len(newV)))


def _split_face(f, mids):
    """Triangulate face ``f`` with midpoints on some edges (``mids[k]`` on edge k -> k+1)."""
    poly = []
    for k in range(3):
        poly.append(f[k])
        if mids[k] is not None:
            poly.append(mids[k])
    # fan from the first original corner is valid for a convex polygon
    return [[poly[0], poly[i], poly[i + 1]] for i in range(1, len(poly) - 1)]


def face_only(base: StressCase) -> StressCase:
    """The faces of the base's face mask only (an open face scan)."""
    from geoface.mesh.core import remove_unreferenced

    if base.roi is None:
        raise ValueError("face_only needs a base with a face mask (ICT)")
    keep = base.roi[base.F].all(1)
    V, F, old = remove_unreferenced(base.V, base.F[keep])
    c = _derived(base, "face_only", V, F, roi=np.ones(len(V), bool))
    return c


def closed_neck(base: StressCase) -> StressCase:
    """The base closed at its longest boundary (the neck) by a flat fan, its other openings
    (eyes, mouth) filled the same way: a closed head."""
    from geoface.mesh.core import boundary_loops

    V, F = base.V.copy(), base.F.copy()
    for loop in boundary_loops(F):
        c = len(V)
        V = np.vstack([V, V[loop].mean(0, keepdims=True)])
        F = np.vstack([F, np.stack([np.roll(loop, -1), loop, np.full(len(loop), c)], 1)])
    k = len(V) - len(base.V)
    return _derived(base, "closed_neck", V, F, roi=_pad(base.roi, k))


def decimated(base: StressCase, faces: int = 1000) -> StressCase:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(base.V, base.F))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(faces), preserveboundary=True, preservetopology=True,
                                                planarquadric=True, autoclean=True)
    m = ms.current_mesh()
    V, F = np.asarray(m.vertex_matrix(), float), np.asarray(m.face_matrix(), np.int64)
    roi = None
    if base.roi is not None:
        from scipy.spatial import cKDTree

        roi = base.roi[cKDTree(base.V).query(V)[1]]
    return _derived(base, "decimated", V, F, roi=roi)


def photo(base: StressCase, seed: int = 0) -> StressCase:
    """A 3D photo of a head: 18 holes and 3 floating components."""
    c = with_holes(base, 18, seed)
    rng = np.random.default_rng(seed + 1)
    P, T = _debris_pieces(c.V, 3, rng, scale=0.02)
    return _derived(base, "photo", np.vstack([c.V, P]), np.vstack([c.F, T]), roi=_pad(c.roi, len(P)))


def raw_face(base: StressCase, vertices: int = 47000, seed: int = 0) -> StressCase:
    """A raw face scan: the face only, subdivided to about ``vertices``, with 12 double-sided
    fins and 5 floating components."""
    import trimesh

    f = face_only(base)
    V, F = f.V, f.F
    while len(V) < vertices / 3.2:
        V, F = trimesh.remesh.subdivide(V, F)
    V, F = np.asarray(V, float), np.asarray(F, np.int64)
    mid = _derived(base, "raw_face", V, F, roi=np.ones(len(V), bool))
    mid = with_fins(mid, 12, seed)
    rng = np.random.default_rng(seed + 2)
    P, T = _debris_pieces(mid.V, 5, rng)
    return _derived(base, "raw_face", np.vstack([mid.V, P]), np.vstack([mid.F, T]), roi=_pad(mid.roi, len(P)))


def soup(base: StressCase) -> StressCase:
    """The base, to be written as an OBJ whose every corner has its own normal."""
    c = _derived(base, "soup", base.V, base.F, roi=base.roi)
    c.soup = True
    return c


def write_soup_obj(path: Path, V: np.ndarray, F: np.ndarray) -> None:
    """An OBJ with one normal per face corner (``f a//k b//k+1 c//k+2``), as exporters that
    split normals at every edge write them: a loader that keeps corners apart (trimesh with
    ``process=False``) reads a triangle soup."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    rng = np.random.default_rng(0)
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in V]
    N = np.repeat(n, 3, axis=0) + 1e-3 * rng.standard_normal((3 * len(F), 3))  # every corner its own
    lines += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in N]
    for i, (a, b, c) in enumerate(F.tolist()):
        lines.append(f"f {a + 1}//{3 * i + 1} {b + 1}//{3 * i + 2} {c + 1}//{3 * i + 3}")
    Path(path).write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------------------------- checks
def landmark_pixels(folder, landmarks: dict, *, subpixel: bool = False) -> dict:
    """Where each landmark lands in the geometry images of ``folder``: the (row, column) of the
    pixel whose decoded position (``position.png``) is nearest to it, and that distance.
    ``subpixel``: the row and column refined to a fraction of a pixel (the positions about that
    pixel fitted linearly, the landmark's offset solved in the least-squares sense)."""
    from scipy.spatial import cKDTree

    from geoface.gimage import load_gimage

    gi = load_gimage(folder)
    P = gi.positions()
    N = gi.resolution
    ok = gi.mask.ravel()
    idx = np.flatnonzero(ok)
    tree = cKDTree(P.reshape(-1, 3)[idx])
    out = {}
    for k, p in landmarks.items():
        d, i = tree.query(np.asarray(p, float))
        r, c = divmod(int(idx[i]), N)
        if subpixel and 0 < r < N - 1 and 0 < c < N - 1 and gi.mask[r - 1:r + 2, c - 1:c + 2].all():
            J = np.column_stack([(P[r + 1, c] - P[r - 1, c]) / 2, (P[r, c + 1] - P[r, c - 1]) / 2])  # d pos / d (row, col)
            dr, dc = np.linalg.lstsq(J, np.asarray(p, float) - P[r, c], rcond=None)[0]
            if abs(dr) <= 1 and abs(dc) <= 1:
                r, c = r + float(dr), c + float(dc)
        out[k] = (r, c, float(d))
    return out


def upright_problems(pixels: dict, N: int) -> list[str]:
    """What is wrong with a face's place in a default image (empty when it is upright and
    centred): the nose within the middle 40% of the width, the eyes above the nose and on either
    side of it (the subject's right eye on the image's left, as in a photograph), the chin below
    the nose."""
    probs = []
    nr, nc = pixels["nose"][:2]
    if abs(nc - (N - 1) / 2) > 0.2 * N:
        probs.append(f"nose not centred (column {nc} of {N})")
    for eye in ("eye_right", "eye_left"):
        if eye in pixels and pixels[eye][0] >= nr:
            probs.append(f"{eye} not above the nose (rows {pixels[eye][0]} vs {nr})")
    if "eye_right" in pixels and "eye_left" in pixels:
        if not pixels["eye_right"][1] < nc < pixels["eye_left"][1]:
            probs.append(f"eyes not on either side of the nose, right eye left (columns {pixels['eye_right'][1]}, {nc}, "
                         f"{pixels['eye_left'][1]})")
    if "chin" in pixels and pixels["chin"][0] <= nr:
        probs.append(f"chin not below the nose (rows {pixels['chin'][0]} vs {nr})")
    return probs


# ----------------------------------------------------------------------------------- sets
def stress_cases(*, meshes=tuple(REAL), ict=(0,), kinds=CASE_KINDS, conventions=tuple(CONVENTIONS) + (TILTED,),
                 mesh_folder: Path | None = None, ict_variants: int | None = None):
    """Yield the stress cases (lazily: each is built when it is reached).  ``ict_variants``: only
    the first that many ICT heads get the variants; the others appear as they are (Y-up)."""
    bases = [real_base(n, mesh_folder) for n in meshes] + [ict_base(s) for s in ict]
    n_real = len(meshes)
    for i, b in enumerate(bases):
        if ict_variants is not None and i - n_real >= ict_variants:
            yield b
            continue
        ict_b = b.roi is not None
        variants = [b]
        if ict_b and "face_only" in kinds:
            variants.append(face_only(b))
        if ict_b and "closed_neck" in kinds:
            variants.append(closed_neck(b))
        for v in variants:
            if "axes" in kinds:
                for conv in conventions:
                    yield v if conv == "y-up" and v.kind == "base" else moved(v, conv)
        if "fins" in kinds:
            yield with_fins(b)
        if "debris" in kinds:
            yield with_debris(b)
        if "soup" in kinds:
            yield soup(b)
        if "holes" in kinds and len(b.F) > 4000:
            yield with_holes(b)
        if "slivers" in kinds:
            yield with_slivers(b)
        if "decimated" in kinds and len(b.F) > 2000:
            yield decimated(b)
        if ict_b and "photo" in kinds:
            yield photo(b)
        if ict_b and "raw_face" in kinds:
            yield raw_face(b)
        if "turned" in kinds:
            for j, v in enumerate(variants):
                yield turned(v, 7 + 11 * j)
        if ict_b and "torso" in kinds:
            yield with_torso(b)
        if ict_b and "plinth" in kinds:
            yield with_plinth(b)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--meshes", nargs="*", default=list(REAL))
    ap.add_argument("--ict", type=int, default=1, help="ICT heads (seeds 0..N-1)")
    ap.add_argument("--kinds", nargs="*", default=list(CASE_KINDS), choices=CASE_KINDS)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    entries = []
    for c in stress_cases(meshes=args.meshes, ict=range(args.ict), kinds=args.kinds):
        file = c.save(args.out)
        e = c.to_json(file)
        if c.roi is not None:
            np.save(args.out / f"{c.name}_roi.npy", c.roi)
            e["roi"] = f"{c.name}_roi.npy"
        entries.append(e)
        print(f"{c.name}: {len(c.V)} vertices, {len(c.F)} faces")
    (args.out / "cases.json").write_text(json.dumps(entries, indent=1))


if __name__ == "__main__":
    main()
