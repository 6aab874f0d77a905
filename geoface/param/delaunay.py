"""Intrinsic Delaunay triangulations with Ptolemy flips, for robust discrete conformal maps.

With a fixed triangulation the discrete conformal (Ricci flow) problem may have no
solution without degenerate triangles (pleated scans, needle-shaped regions).  Keeping
the triangulation *intrinsically Delaunay* for the current metric, and giving the new
edge of every flip its length by the Ptolemy relation

    l_CD * l_AB = l_AD * l_BC + l_DB * l_CA,

makes the problem always solvable (Springborn 2019; Gu, Luo, Sun & Wu 2018; Gillespie,
Springborn & Crane 2021): Ptolemy flips preserve the discrete conformal class, commute
with vertex scaling, and the energy is continuous (C^2) across them.

An intrinsic triangulation may have several edges between two vertices, or an edge from
a vertex to itself, so edges are identified by half-edges and twins, never by vertex
pairs.  Half-edge ``h = 3 f + k`` runs from ``F[f, k]`` to ``F[f, (k+1) % 3]``.

The Delaunay test uses the algebraic form ``cos a + cos b >= 0`` with
``2 cos a = (b^2 + c^2 - a^2) / (b c)``, defined even for lengths that violate the
triangle inequality (which the Delaunay triangulation then repairs).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterizationError
from ..mesh.core import halfedge_twins


class IntrinsicTriangulation:
    """Faces, per-half-edge base lengths (before vertex scaling) and twins.

    Attributes
    ----------
    F : (m, 3) int64 — current faces (counter-clockwise)
    L : (3m,) float64 — base length of every half-edge
    twin : (3m,) int64 — opposite half-edge, -1 on the boundary
    flips : int — flips performed so far
    log : list — every flip in order, ``(h, t, None)`` for a Ptolemy flip of half-edge
        ``h`` (twin ``t``) and ``(h, t, (l_cd, u))`` for a Euclidean flip in the flat
        metric scaled by ``u`` (new scaled length ``l_cd``); replayed by
        :mod:`geoface.param.tracking` to carry points of the input mesh through the flips
    """

    def __init__(self, F: np.ndarray, l: np.ndarray):
        self.F = np.array(F, np.int64)
        self.F0 = self.F.copy()
        # l[f, k] is opposite corner k, i.e. half-edge 3f + (k+1) % 3
        self.L = np.asarray(l, np.float64)[:, [2, 0, 1]].ravel().copy()
        self.L0 = self.L.copy()
        self.twin = halfedge_twins(self.F)
        self.flips = 0
        self.log: list = []

    def copy(self) -> "IntrinsicTriangulation":
        """An independent copy: the arrays and the flip log copied (the log's entries, tuples that
        nothing changes once written, are shared): far cheaper than ``copy.deepcopy`` on a flow's log."""
        c = object.__new__(type(self))
        c.__dict__.update({k: v.copy(order="K") if isinstance(v, np.ndarray) else list(v) if isinstance(v, list) else v
                           for k, v in self.__dict__.items()})
        return c

    def corner_lengths(self, u: np.ndarray) -> np.ndarray:
        """``(m, 3)`` scaled lengths opposite each corner (the layout of ``l`` everywhere)."""
        Ls = self.scaled_halfedges(u).reshape(-1, 3)
        return Ls[:, [1, 2, 0]]

    def scaled_halfedges(self, u: np.ndarray) -> np.ndarray:
        src = self.F.ravel()
        dst = self.F[:, [1, 2, 0]].ravel()
        return self.L * np.exp(0.5 * (u[src] + u[dst]))

    def make_delaunay(self, u: np.ndarray, max_flips: int | None = None) -> int:
        """Flip (Ptolemy) until every interior edge is Delaunay for the metric scaled by ``u``."""
        F, twin = self.F, self.twin
        Ls = self.scaled_halfedges(u)
        src = F.ravel()
        dst = F[:, [1, 2, 0]].ravel()

        def cos2(h: int) -> float:  # 2 cos of the angle opposite half-edge h
            f, k = divmod(h, 3)
            a, b, c = Ls[h], Ls[3 * f + (k + 1) % 3], Ls[3 * f + (k + 2) % 3]
            return (b * b + c * c - a * a) / (b * c)

        # vectorised first pass to find the candidates
        cand = np.flatnonzero((twin >= 0) & (np.arange(len(twin)) < twin))
        if len(cand) == 0:
            return 0
        Lf = Ls.reshape(-1, 3)

        def cos2_vec(h):
            f, k = h // 3, h % 3
            a, b, c = Ls[h], Lf[f, (k + 1) % 3], Lf[f, (k + 2) % 3]
            return (b * b + c * c - a * a) / (b * c)

        bad = cos2_vec(cand) + cos2_vec(twin[cand]) < -1e-12
        stack = cand[bad].tolist()
        limit = max_flips if max_flips is not None else 50 * len(F) + 1000
        done = 0
        while stack:
            h = stack.pop()
            t = int(twin[h])
            if t < 0 or t // 3 == h // 3 or cos2(h) + cos2(t) >= -1e-12:
                continue
            six = set(range(3 * (h // 3), 3 * (h // 3) + 3)) | set(range(3 * (t // 3), 3 * (t // 3) + 3))
            outer_twins = {int(twin[x]) for x in six} - {h, t}
            if outer_twins & six:  # a face glued to its neighbour twice: not flippable
                continue
            outer = self._flip(h, t, Ls, u, src, dst)
            done += 1
            if done > limit:
                raise ParameterizationError("intrinsic Delaunay flips did not terminate")
            stack.extend(outer)
        self.flips += done
        return done

    def _flip(self, h: int, t: int, Ls: np.ndarray, u: np.ndarray, src: np.ndarray, dst: np.ndarray) -> list[int]:
        F, L, twin = self.F, self.L, self.twin
        f, k = divmod(h, 3)
        g, m = divmod(t, 3)
        A, B, C = int(F[f, k]), int(F[f, (k + 1) % 3]), int(F[f, (k + 2) % 3])
        D = int(F[g, (m + 2) % 3])
        hBC, hCA = 3 * f + (k + 1) % 3, 3 * f + (k + 2) % 3
        hAD, hDB = 3 * g + (m + 1) % 3, 3 * g + (m + 2) % 3
        lBC, lCA, lAD, lDB = float(L[hBC]), float(L[hCA]), float(L[hAD]), float(L[hDB])
        tBC, tCA, tAD, tDB = int(twin[hBC]), int(twin[hCA]), int(twin[hAD]), int(twin[hDB])
        # Ptolemy on base lengths (invariant under vertex scaling)
        l_cd = (lAD * lBC + lDB * lCA) / float(L[h])
        # new faces f = (C, A, D), g = (D, B, C): half-edges CA, AD, DC = 3f, 3f+1, 3f+2 and
        # DB, BC, CD = 3g, 3g+1, 3g+2
        F[f] = (C, A, D)
        F[g] = (D, B, C)
        f3, g3 = 3 * f, 3 * g
        for x, length, tw in ((f3, lCA, tCA), (f3 + 1, lAD, tAD), (g3, lDB, tDB), (g3 + 1, lBC, tBC)):
            L[x] = length
            twin[x] = tw
            if tw >= 0:
                twin[tw] = x
        L[f3 + 2] = L[g3 + 2] = l_cd
        twin[f3 + 2], twin[g3 + 2] = g3 + 2, f3 + 2
        self.log.append((h, t, None))
        # refresh cached scaled lengths and endpoints of the six half-edges
        for x, a, b in ((f3, C, A), (f3 + 1, A, D), (f3 + 2, D, C), (g3, D, B), (g3 + 1, B, C), (g3 + 2, C, D)):
            src[x], dst[x] = a, b
            Ls[x] = L[x] * math.exp(0.5 * (u[a] + u[b]))
        return [g3 + 1, f3, f3 + 1, g3]


def flip_flat_degenerate(tri: IntrinsicTriangulation, u: np.ndarray, tol: float = 1e-9) -> int:
    """In a converged flat metric, flip the long edge of every triangle with an angle of pi.

    Such a triangle (a boundary vertex lying on the straight segment between its
    neighbours, with one triangle) cannot be laid out with positive area.  In the flat
    metric its long edge and the triangle beyond form a quadrilateral in which the other
    diagonal has a Euclidean length (law of cosines); the flip changes the triangulation,
    not the metric.  Returns the number of flips.
    """
    from .intrinsic import corner_angles

    done = 0
    for _ in range(3):
        lc = tri.corner_lengths(u)
        ang = corner_angles(lc)
        bad = np.flatnonzero(ang.max(1) > np.pi - tol)
        if len(bad) == 0:
            break
        Ls = tri.scaled_halfedges(u)
        for f in bad.tolist():
            kk = int(np.argmax(ang[f]))  # corner with angle pi: its opposite half-edge is long
            h = 3 * f + (kk + 1) % 3
            t = int(tri.twin[h])
            if t < 0 or t // 3 == f:
                continue
            g, m = divmod(t, 3)
            # quad: f = (A, B, C) with h = A -> B, apex C (on segment AB); g = (B, A, D)
            l_ab = Ls[h]
            l_ac = Ls[3 * f + kk]  # half-edge C -> A
            l_ad = Ls[3 * g + (m + 1) % 3]  # A -> D
            l_db = Ls[3 * g + (m + 2) % 3]  # D -> B
            cos_a = (l_ab**2 + l_ad**2 - l_db**2) / (2 * l_ab * l_ad)  # angle at A in g
            l_cd = np.sqrt(max(l_ac**2 + l_ad**2 - 2 * l_ac * l_ad * cos_a, 0.0))
            src = tri.F.ravel().copy()
            dst = tri.F[:, [1, 2, 0]].ravel().copy()
            tri._flip(h, t, Ls, u, src, dst)
            # the Ptolemy length was written; replace it by the Euclidean one (base length)
            for x in (3 * f + 2, 3 * g + 2):
                a_, b_ = tri.F[x // 3, x % 3], tri.F[x // 3, (x % 3 + 1) % 3]
                tri.L[x] = l_cd * np.exp(-0.5 * (u[a_] + u[b_]))
            tri.log[-1] = (h, t, (float(l_cd), np.array(u, np.float64)))
            done += 1
            break  # lengths changed: recompute before the next one
    tri.flips += done
    return done
