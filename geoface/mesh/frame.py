"""Which way a mesh faces: an up / front / right frame found from the geometry itself.

Scans arrive facing any horizontal direction (a bust scanned facing −Z, a head facing +X), so a
fixed camera along +Z often shows the back of the head. :func:`mesh_frame` finds where the
*front* is, given which way is *up* (+Y by default: the convention of OBJ, PLY and glTF and of
most scanners; pass ``up`` for Z-up data):

1. **A face region, when known** (a face mask or landmarks, as ``geoface synth`` writes them):
   front = from the surface's centroid towards the face's, made horizontal.
2. **Otherwise, from the shape.** The surface is sampled uniformly by area (so results do not
   depend on the triangulation), then

   * *the front–back axis*: heads, animals' heads and cars are mirror-symmetric about a
     vertical plane; the horizontal direction whose mirror reflection best maps the surface
     onto itself (mean nearest-point distance, 3° steps) is left–right, and front–back is
     perpendicular to it. When no plane is clearly better than the rest (a posed body), the
     front–back axis is the horizontal principal axis of smaller extent (shoulders are wider
     than deep).
   * *its sign*: for a standing figure (taller than twice its width), the feet — toes reach
     further forward of the shins than heels reach back. Otherwise, where the detail is: the
     surface variation of each sample's 24 nearest neighbours (smallest over summed
     eigenvalue of their covariance: 0 on a plane or a sphere much larger than the
     neighbourhood, large at a nose, lips, eyelids, a snout), its first moment along the axis.
     A face carries the detail; the back of a head is a smooth dome.

A sheet standing upright (thinner than 5 % of its width horizontally: a rectangle, a relief,
a face mask) is looked at from the side its faces' normals point to.

The result is a heuristic for pictures, not a measurement: it is right on every head, face,
bust and animal in the test data and on ICT heads at any yaw (see ``tests/mesh/test_frame.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import GeofaceError
from .core import check_mesh, face_areas, face_normals_unnormalized

__all__ = ["MeshFrame", "mesh_frame", "points_frame", "parse_up", "axis_text", "view_direction", "VIEWS"]

#: named views: the camera sits on this side of the mesh (in the frame's right/up/front axes)
VIEWS = {
    "front": (0.0, 0.0, 1.0), "back": (0.0, 0.0, -1.0), "left": (-1.0, 0.0, 0.0), "right": (1.0, 0.0, 0.0),
    "top": (0.0, 1.0, 0.0), "bottom": (0.0, -1.0, 0.0), "iso": (0.55, 0.45, 0.70),
}
_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class MeshFrame:
    """``up``, ``front`` (the direction the mesh faces) and ``right`` (= up × front: the right of
    a viewer looking at the front, i.e. the mesh's own left), unit and orthogonal; ``center`` and ``radius`` of the surface (bounding-box centre, half diagonal);
    ``how``: "face region", "symmetry", "principal axes" (which told the front–back axis), plus
    the sign cue."""

    up: np.ndarray
    front: np.ndarray
    right: np.ndarray
    center: np.ndarray
    radius: float
    how: str

    def camera(self, view: str = "front", distance: float = 2.6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, focal point, view-up) of a camera looking at the mesh from ``view``."""
        d = view_direction(self, view)
        up = self.up if abs(float(d @ self.up)) < 0.99 else -self.front if d @ self.up > 0 else self.front
        return self.center + distance * self.radius * d, self.center.copy(), up


def view_direction(frame: MeshFrame, view: str) -> np.ndarray:
    """Unit vector from the mesh's centre towards the camera for a named view."""
    if view not in VIEWS:
        raise GeofaceError(f"view must be one of {', '.join(VIEWS)}; got {view!r}")
    r, u, f = VIEWS[view]
    d = r * frame.right + u * frame.up + f * frame.front
    return d / np.linalg.norm(d)


def axis_text(v, within_degrees: float = 5.0) -> str:
    """A direction as its axis name (``+y``, ``-z``) when within ``within_degrees`` of it, else
    its three numbers: the inverse of :func:`parse_up` for messages.

    >>> axis_text([0, -1, 0]), axis_text([0.05, 0.9987, 0]), axis_text([0.05, 0.9987, 0], 0.08)
    ('-y', '+y', '(0.05, 1.00, 0.00)')
    """
    v = np.asarray(v, float)
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > np.cos(np.radians(within_degrees)):
        return ("-" if v[k] < 0 else "+") + "xyz"[k]
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def parse_up(text) -> np.ndarray:
    """``"+y"``, ``"-z"``, ``"x"`` or three numbers (``"0,0,1"``) → a unit vector."""
    if text is None:
        return np.array([0.0, 1.0, 0.0])
    if not isinstance(text, str):
        v = np.asarray(text, np.float64).reshape(-1)
    else:
        t = text.strip().lower()
        sign = -1.0 if t.startswith("-") else 1.0
        t = t.lstrip("+-")
        if t in _AXES:
            v = np.zeros(3)
            v[_AXES[t]] = sign
        else:
            try:
                v = np.array([float(x) for x in text.replace(" ", "").split(",")], np.float64)
            except ValueError:
                raise GeofaceError(f"up must be +x, -x, +y, -y, +z, -z or three numbers; got {text!r}") from None
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
        raise GeofaceError(f"up must be a non-zero 3-vector; got {text!r}")
    return v / np.linalg.norm(v)


def _sample_surface(V, F, n: int, rng) -> np.ndarray:
    A = face_areas(V, F)
    total = A.sum()
    if not np.isfinite(total) or total <= 0:
        raise GeofaceError("the mesh has no area to look at")
    f = rng.choice(len(F), size=n, p=A / total)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.column_stack([1 - s, s * (1 - r2), s * r2])
    return np.einsum("nk,nkd->nd", w, V[F[f]])


def _horizontal_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(up, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def mesh_frame(V, F, *, up=None, face=None, samples: int = 12000, seed: int = 0) -> MeshFrame:
    """The mesh's up / front / right frame (see the module's description).

    Parameters
    ----------
    V, F : the mesh (any triangulation; several components, inconsistent orientation are fine)
    up : the up direction (anything :func:`parse_up` takes); default +Y
    face : optional vertex indices or a boolean vertex mask of the face region (landmarks work
        too): front then points from the surface's centroid towards theirs
    samples : surface samples for the shape cues
    """
    V, F = check_mesh(V, F)
    up = parse_up(up)
    lo, hi = V[np.unique(F)].min(0), V[np.unique(F)].max(0)
    center, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    rng = np.random.default_rng(seed)
    P = _sample_surface(V, F, int(samples), rng)
    if face is not None:
        idx = np.asarray(face)
        idx = np.flatnonzero(idx) if idx.dtype == bool else idx.astype(np.int64).reshape(-1)
        if len(idx) == 0 or idx.min() < 0 or idx.max() >= len(V):
            raise GeofaceError(f"face region: vertex indices must be in [0, {len(V)}); got {len(idx)} indices")
        return _finish(up, V[idx].mean(0) - P.mean(0), center, radius, "face region")
    # a sheet standing upright (a rectangle, a relief, a face mask): look at its face, not its edge
    X = P - P.mean(0)
    H = X - np.outer(X @ up, up)
    w, vec = np.linalg.eigh(H.T @ H)
    order = np.argsort(w)[::-1]
    if w[order[1]] <= 0.05 ** 2 * w[order[0]]:  # the thinner horizontal extent < 5 % of the wider
        axis = vec[:, order[1]]
        n = face_normals_unnormalized(V, F).sum(0)  # where its (oriented) side faces
        s = float(n @ axis)
        if abs(s) < 1e-9 * max(float(np.abs(n).sum()), 1e-300):
            s = float(axis @ _horizontal_basis(up)[1])  # unoriented: the +Z side, as a fixed camera
        return _finish(up, axis if s >= 0 else -axis, center, radius, "flat, its side")
    h = X @ up
    if np.ptp(h) <= 0.05 * 2 * np.sqrt(w[order[0]] / len(X)) * 1.7:  # lying flat: look down on it
        n = face_normals_unnormalized(V, F).sum(0)
        top = up if float(n @ up) >= 0 else -up
        new_up = vec[:, order[0]]  # its longer side upright in the picture (−Z for a square, Y up)
        if w[order[0]] < 1.1 * w[order[1]]:
            new_up = _horizontal_basis(up)[0]
        return MeshFrame(up=new_up, front=top, right=np.cross(new_up, top), center=center, radius=radius,
                         how="lying flat, from above")
    return _frame_of_samples(P, up, center, radius)


def points_frame(P, *, up=None, samples: int = 12000, seed: int = 0) -> MeshFrame:
    """:func:`mesh_frame` for a point set (e.g. the centres of Gaussian splats): the points stand
    in for the surface samples (subsampled to ``samples``)."""
    P = np.asarray(P, np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 30 or not np.isfinite(P).all():
        raise GeofaceError(f"points: need at least 30 finite 3D points; got shape {P.shape}")
    up = parse_up(up)
    lo, hi = P.min(0), P.max(0)
    if len(P) > samples:
        P = P[np.random.default_rng(seed).choice(len(P), samples, replace=False)]
    return _frame_of_samples(P, up, (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2)


def _finish(up, front, center, radius, how) -> MeshFrame:
    front = front - (front @ up) * up
    n = np.linalg.norm(front)
    front = _horizontal_basis(up)[1] if n < 1e-9 else front / n
    return MeshFrame(up=up, front=front, right=np.cross(up, front), center=center, radius=radius, how=how)


def _frame_of_samples(P, up, center, radius) -> MeshFrame:
    from scipy.spatial import cKDTree

    if radius <= 0:
        raise GeofaceError("the mesh has no extent to look at")
    c = P.mean(0)
    X = P - c
    h = X @ up
    H = X - np.outer(h, up)  # horizontal parts
    e1, e2 = _horizontal_basis(up)
    tree = cKDTree(P)
    R = 2 * radius
    # the vertical plane of mirror symmetry, if there is one: every 9° on a thousand samples,
    # then every 3° about the three best of those on three thousand
    def mirror_error(t, pts):
        a = np.cos(t) * e1 + np.sin(t) * e2
        return tree.query(pts - 2 * np.outer(pts @ a, a) + c)[0].mean() / R

    coarse = np.radians(np.arange(0.0, 180.0, 9.0))
    few = X[:: max(1, len(X) // 1000)]
    errs = np.array([mirror_error(t, few) for t in coarse])
    sub = X[:: max(1, len(X) // 3000)]
    fine = {round(9.0 * k + d) % 180 for k in np.argsort(errs)[:3] for d in (-6.0, -3.0, 0.0, 3.0, 6.0)}
    th, err = min(((np.radians(deg), mirror_error(np.radians(deg), sub)) for deg in sorted(fine)), key=lambda x: x[1])
    if err < 0.5 * np.median(errs):
        lateral = np.cos(th) * e1 + np.sin(th) * e2
        axis, how = np.cross(up, lateral), "symmetry"
    else:
        w, vec = np.linalg.eigh(H.T @ H)  # two horizontal axes (the third eigenvalue ~ 0 along up)
        horiz = [vec[:, k] for k in np.argsort(w)[::-1][:2]]
        axis, how = horiz[1], "principal axes"
    x = H @ axis
    width = float(np.ptp(H @ np.cross(up, axis)))
    height = float(np.ptp(h))
    if height > 2.0 * max(width, float(np.ptp(x))):  # a standing figure: the feet
        lo_h = h.min()
        feet = x[h < lo_h + 0.03 * height]
        shins = x[(h > lo_h + 0.10 * height) & (h < lo_h + 0.18 * height)]
        score = float(feet.mean() - shins.mean()) if len(feet) and len(shins) else 0.0
        how += ", feet"
    else:  # where the detail is
        _, nb = tree.query(P, 24)
        Q = P[nb] - P[nb].mean(1, keepdims=True)
        ev = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", Q, Q))
        var = ev[:, 0] / np.maximum(ev.sum(1), 1e-300)
        score = float(np.sum(var * x))
        how += ", detail"
    return _finish(up, axis if score >= 0 else -axis, center, radius, how)
