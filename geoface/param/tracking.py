"""Carry points of the input mesh through intrinsic (Ptolemy) flips: the actual conformal map.

When the Ricci flow keeps an intrinsic Delaunay triangulation (``flips`` in
:class:`geoface.param.ricci.RicciFlowSolver`), its final triangles are not triangles of the
input mesh, and the conformal map from the input surface to the plane is not linear on
input triangles: it is *projective* on each piece of the common refinement of the two
triangulations (Gillespie, Springborn & Crane 2021).  Distortion measured on the chord
triangles of the intrinsic triangulation says nothing about that map; this module
evaluates the map itself at any point of the input mesh.

Coordinates
-----------
A Euclidean triangle is mapped onto an ideal hyperbolic triangle (Klein model) by the
projective map taking its circumcircle to the circle at infinity.  In barycentric
coordinates ``b`` of a triangle whose side opposite corner ``i`` has length ``l_i`` the
point's *conformal coordinates* are ``q_i = b_i / l_i^2`` (up to scale): the circumcircle
``sum_i l_i^2 b_j b_k = 0`` becomes ``sum_i q_j q_k = 0`` whatever the lengths.  Hence

* vertex scaling ``l_ij -> exp((u_i + u_j)/2) l_ij`` maps ``b_i -> b_i exp(-u_i)`` (normalised):
  the circumcircle-preserving interpolation of a discrete conformal map;
* a Ptolemy flip of edge ``AB`` in the quad ``ABC | BAD`` changes no point: lay out the
  quad's ideal quadrilateral in the Klein disk (``A, B, C`` equilateral, ``D`` on the arc
  opposite ``C`` where the cross-ratio ``l_AC l_BD / (l_AD l_BC)`` of the lengths puts it),
  read each point's Klein position from its old triangle and its coordinates from the new
  one.  Ptolemy flips commute with vertex scaling, so all of this happens on the *base*
  lengths (before scaling) and the final ``u`` is applied once at the end.

A Euclidean flip of a degenerate flat triangle (:func:`geoface.param.delaunay.flip_flat_degenerate`)
is replayed in the flat metric it was made in.
"""

from __future__ import annotations

import numpy as np

from ..mesh.core import halfedge_twins
from .delaunay import IntrinsicTriangulation

_SQ3 = np.sqrt(3.0)
_XA = np.array([1.0, 0.0])
_XB = np.array([-0.5, 0.5 * _SQ3])
_XC = np.array([-0.5, -0.5 * _SQ3])


def _bary2(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(k, 3)`` of 2D points ``P (k, 2)`` in triangle ``X (3, 2)``."""
    d1, d2 = X[1] - X[0], X[2] - X[0]
    det = d1[0] * d2[1] - d1[1] * d2[0]
    r = P - X[0]
    b1 = (r[:, 0] * d2[1] - r[:, 1] * d2[0]) / det
    b2 = (d1[0] * r[:, 1] - d1[1] * r[:, 0]) / det
    return np.stack([1.0 - b1 - b2, b1, b2], 1)


def _normalise(b: np.ndarray) -> np.ndarray:
    b = np.maximum(b, 0.0)
    s = b.sum(1, keepdims=True)
    return b / np.where(s > 0, s, 1.0)


def _klein_D(l_ac: float, l_bc: float, l_ad: float, l_db: float) -> np.ndarray:
    """Klein position of ``D`` given equilateral ``A, B, C`` (the module docstring)."""
    rho = (l_ac * l_db) / (l_ad * l_bc)  # = |X_B - X_D| / |X_A - X_D|
    x = np.arctan2(0.5 * _SQ3, rho + 0.5)  # half the arc angle from A to D, in (0, pi/3)
    return np.array([np.cos(2 * x), np.sin(2 * x)])


def _relocate(Pk: np.ndarray, X_new: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Side (0: first new triangle, 1: second) and barycentrics of points in the new triangles."""
    b0 = _bary2(Pk, X_new[0])
    b1 = _bary2(Pk, X_new[1])
    side = (b1.min(1) > b0.min(1)).astype(np.int64)
    return side, np.where(side[:, None] == 1, b1, b0)


class FlipTracker:
    """Replays a flip log on the input triangulation, carrying points along.

    Parameters
    ----------
    F0 : (m, 3) int64 — the triangulation the flips started from
    L0 : (3m,) float64 — its half-edge base lengths (:class:`IntrinsicTriangulation` layout)
    log : list — :attr:`IntrinsicTriangulation.log`
    """

    def __init__(self, F0: np.ndarray, L0: np.ndarray, log: list):
        self.F0 = np.asarray(F0, np.int64)
        self.L0 = np.asarray(L0, np.float64)
        self.log = list(log)

    @classmethod
    def from_triangulation(cls, tri: IntrinsicTriangulation) -> "FlipTracker":
        return cls(tri.F0, tri.L0, tri.log)

    def track(self, face: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points given as (face of ``F0``, barycentrics) → (face, base-frame barycentrics)
        of the final triangulation.  ``face (k,)``, ``bary (k, 3)`` in ``F0``'s corner order."""
        face = np.asarray(face, np.int64).copy()
        bary = _normalise(np.asarray(bary, np.float64).reshape(-1, 3).copy())
        tri = IntrinsicTriangulation.__new__(IntrinsicTriangulation)
        tri.F, tri.L, tri.twin = self.F0.copy(), self.L0.copy(), halfedge_twins(self.F0)
        tri.F0, tri.L0, tri.flips, tri.log = self.F0, self.L0, 0, []
        n = int(self.F0.max()) + 1
        zero = np.zeros(n)
        Ls = tri.L.copy()
        src = tri.F.ravel().copy()
        dst = tri.F[:, [1, 2, 0]].ravel().copy()
        order = np.argsort(face, kind="stable")
        cuts = np.searchsorted(face[order], np.arange(len(self.F0) + 1))
        members = {f: order[cuts[f] : cuts[f + 1]] for f in np.unique(face).tolist()}
        empty = np.zeros(0, np.int64)
        for h, t, euclid in self.log:
            f, k = divmod(int(h), 3)
            g, m = divmod(int(t), 3)
            pf, pg = members.get(f, empty), members.get(g, empty)
            L, F = tri.L, tri.F
            if len(pf) or len(pg):
                # quad: f = (A, B, C) with h = A -> B, g = (B, A, D)
                ia, ib, ic = k, (k + 1) % 3, (k + 2) % 3
                jb, ja, jd = m, (m + 1) % 3, (m + 2) % 3
                A, B, C, D = F[f, ia], F[f, ib], F[f, ic], F[g, jd]
                l_ab, l_bc, l_ca = L[h], L[3 * f + ib], L[3 * f + ic]
                l_ad, l_db = L[3 * g + ja], L[3 * g + jd]
                bf = bary[pf][:, [ia, ib, ic]]  # (A, B, C)
                bg = bary[pg][:, [jb, ja, jd]]  # (B, A, D)
                if euclid is None:
                    new_face, new_bary = self._ptolemy(bf, bg, l_ab, l_bc, l_ca, l_ad, l_db)
                else:
                    new_face, new_bary = self._euclid(bf, bg, (A, B, C, D), (l_ab, l_bc, l_ca, l_ad, l_db), euclid)
            tri._flip(int(h), int(t), Ls, zero, src, dst)
            if euclid is not None:
                l_cd, u = euclid
                for x in (3 * f + 2, 3 * g + 2):
                    a_, b_ = tri.F[x // 3, x % 3], tri.F[x // 3, (x % 3 + 1) % 3]
                    tri.L[x] = l_cd * np.exp(-0.5 * (u[a_] + u[b_]))
            if len(pf) or len(pg):
                pts = np.concatenate([pf, pg])
                face[pts] = np.where(new_face == 0, f, g)
                bary[pts] = new_bary  # already in the new faces' corner order
                members[f] = pts[new_face == 0]
                members[g] = pts[new_face == 1]
        self.F_final = tri.F
        self.L_final = tri.L
        return face, bary

    @staticmethod
    def _ptolemy(bf, bg, l_ab, l_bc, l_ca, l_ad, l_db):
        """Ptolemy flip in the Klein model; new faces (C, A, D) and (D, B, C)."""
        l_cd = (l_ad * l_bc + l_db * l_ca) / l_ab
        XD = _klein_D(l_ca, l_bc, l_ad, l_db)
        # old triangle ABC (equilateral): Klein barycentrics ∝ k_i^2 q_i with all k_i equal
        qf = bf / np.array([l_bc, l_ca, l_ab]) ** 2
        Pf = _normalise(qf) @ np.stack([_XA, _XB, _XC])
        # old triangle BAD
        k_bad = np.array([np.linalg.norm(_XA - XD), np.linalg.norm(_XB - XD), _SQ3])  # opposite B, A, D
        qg = bg / np.array([l_ad, l_db, l_ab]) ** 2
        Pg = _normalise(qg * k_bad**2) @ np.stack([_XB, _XA, XD])
        P = np.concatenate([Pf, Pg])
        T0 = np.stack([_XC, _XA, XD])  # (C, A, D)
        T1 = np.stack([XD, _XB, _XC])  # (D, B, C)
        side, bk = _relocate(P, (T0, T1))
        k0 = np.array([np.linalg.norm(_XA - XD), np.linalg.norm(XD - _XC), _SQ3])  # opposite C, A, D
        k1 = np.array([_SQ3, np.linalg.norm(_XC - XD), np.linalg.norm(XD - _XB)])  # opposite D, B, C
        L0n = np.array([l_ad, l_cd, l_ca])  # base lengths opposite C, A, D
        L1n = np.array([l_bc, l_cd, l_db])  # opposite D, B, C
        kk = np.where(side[:, None] == 1, k1, k0)
        LL = np.where(side[:, None] == 1, L1n, L0n)
        return side, _normalise(bk / kk**2 * LL**2)

    @staticmethod
    def _euclid(bf, bg, verts, lengths, euclid):
        """Euclidean flip in the flat metric scaled by ``u`` (a degenerate triangle)."""
        A, B, C, D = verts
        l_ab, l_bc, l_ca, l_ad, l_db = lengths
        _, u = euclid
        s = lambda i, j: np.exp(0.5 * (u[i] + u[j]))  # noqa: E731
        ab, bc, ca, ad, db = l_ab * s(A, B), l_bc * s(B, C), l_ca * s(C, A), l_ad * s(A, D), l_db * s(D, B)
        XA, XB = np.array([0.0, 0.0]), np.array([ab, 0.0])
        cx = (ab**2 + ca**2 - bc**2) / (2 * ab)
        XC = np.array([cx, np.sqrt(max(ca**2 - cx**2, 0.0))])
        dx = (ab**2 + ad**2 - db**2) / (2 * ab)
        XD = np.array([dx, -np.sqrt(max(ad**2 - dx**2, 0.0))])
        ef = np.exp(-np.array([u[A], u[B], u[C]]))
        eg = np.exp(-np.array([u[B], u[A], u[D]]))
        P = np.concatenate([_normalise(bf * ef) @ np.stack([XA, XB, XC]), _normalise(bg * eg) @ np.stack([XB, XA, XD])])
        side, b = _relocate(P, (np.stack([XC, XA, XD]), np.stack([XD, XB, XC])))
        back = np.where(side[:, None] == 1, np.exp(np.array([u[D], u[B], u[C]])), np.exp(np.array([u[C], u[A], u[D]])))
        return side, _normalise(b * back)


def scale_bary(F: np.ndarray, face: np.ndarray, bary: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Base-frame barycentrics → barycentrics after vertex scaling by ``u``: ``b_i exp(-u_i)``."""
    return _normalise(bary * np.exp(-u[F[face]]))
