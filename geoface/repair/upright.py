"""Which way is up, and where is the front, of a head in any axis convention (``--up auto``).

Scans arrive Y-up (OBJ, glTF), Z-up facing +X (most scanning and acoustics software), Z-up
facing −Y (Blender), lying on their side or upside down, in any unit and far from the origin.
:func:`upright_frame` finds up and front from the shape alone, so the same head in any of these
comes out of ``geoface convert`` as the same images:

1. **Open at the neck** (the longest boundary is a real opening, and the surface reaches far
   beyond it: deeper than 0.55 of the opening's width): up is the normal of the opening's
   plane, pointing into the surface; front from :func:`geoface.mesh.frame.mesh_frame` about it
   (the mirror-symmetry plane and where the detail is).
2. **A face only** (the surface is shallow over its opening: a face scan without the back of
   the head): front is the opening's normal (the face bulges out of its rim); up lies in the
   mirror-symmetry plane through the front, its sign from the nose (below the tip the profile
   falls steeply to the lip, above it slopes gently up the bridge).
3. **Closed**: the bottom is where the head was cut — the largest flat region on the convex
   hull (a neck cap, a bust's base, a torso cut); without one, the face and the nose tell it
   (the mirror-symmetry plane, front where the detail is, up from the nose), and failing those
   the plane the shape rests on most stably.

Each answer says how it was found and whether it is sure (``certain``); where it is not (no
cue clear enough), up falls back to the file's +Y and the reason is given, for one line on the
command line and for ``metrics.json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import GeofaceError
from ..mesh.core import boundary_loops, face_areas, loop_length
from .template import TEMPLATE_FIT, SCAN_POINTS, fit_head_template, surface_samples, template_face_region, turned_fit  # noqa: F401

__all__ = ["UprightFrame", "upright_frame", "template_face_region", "FACE_DEPTH_RATIO"]

#: a surface shallower than this over its opening (depth / the opening's width) is a face only
FACE_DEPTH_RATIO = 0.55
#: the head template fitted half a turn about its up axis within this factor of the best fit: which
#: way the face looks is decided by the surface's detail (a smooth, egg-shaped head fits either way)
TURNED_MARGIN = 1.15
#: a standing figure's head end: the head template fits it closer than this (bodies 0.10-0.12,
#: the ends of a car 0.3)
FIGURE_FIT = 0.15
#: an up (then a front) this close to an axis of the file is taken as that axis (degrees)
SNAP_DEGREES = 15.0
#: a flat region must cover this share of the surface to be taken as the cut at the bottom
FLAT_SHARE = 0.01
#: the nose: the profile's fall over this share of the face's height, below against above
NOSE_BAND = 0.08


@dataclass(frozen=True)
class UprightFrame:
    """``up``, ``front`` (unit, orthogonal); ``kind``: "open at the neck", "face only" or
    "closed"; ``how``: the cues used; ``certain``: whether the cues agreed clearly (else
    ``why`` says what was unclear); ``cues``: the measured numbers, for reports."""

    up: np.ndarray
    front: np.ndarray
    kind: str
    how: str
    certain: bool = True
    why: str = ""
    cues: dict = field(default_factory=dict)
    template: tuple | None = field(default=None, repr=False)  # (R, s, t, fit) of the head template

    def to_dict(self) -> dict:
        return {"up": [float(x) for x in self.up], "front": [float(x) for x in self.front], "kind": self.kind,
                "how": self.how, "certain": bool(self.certain), "why": self.why,
                "cues": {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in self.cues.items()}}


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-300)


def _orthogonal(v, to) -> np.ndarray:
    return _unit(v - (v @ to) * to)


def _opening(V, F, min_opening: float = 0.1):
    """The longest boundary loop, if it is a real opening: (loop, its plane's normal pointing
    into the surface, depth of the surface beyond it / its width, its length / sqrt(area),
    ambiguous) or None.  ``ambiguous``: another loop is more than half as long, so the longest
    may be one hole among holes of its size (a closed scan with holes) - a caller with a better
    cue (the head template) decides."""
    loops = boundary_loops(F)
    if not loops:
        return None
    lengths = [loop_length(V, lp) for lp in loops]
    k = int(np.argmax(lengths))
    loop = loops[k]
    area = float(face_areas(V, F).sum())
    if len(loop) < 8 or lengths[k] < min_opening * np.sqrt(area):
        return None
    ambiguous = len(loops) > 1 and sorted(lengths)[-2] > 0.5 * lengths[k]
    P = V[loop]
    c = P.mean(0)
    _, _, vt = np.linalg.svd(P - c, full_matrices=False)
    n = vt[2]
    A = face_areas(V, F)
    g = (A[:, None] * V[F].mean(1)).sum(0) / A.sum()
    if (g - c) @ n < 0:
        n = -n
    Q = P - c
    inplane = Q - np.outer(Q @ n, n)
    width = 2.0 * float(np.sqrt((inplane ** 2).sum(1).mean())) * np.sqrt(2.0)  # ~ the diameter of a circle
    depth = float(((V[np.unique(F)] - c) @ n).max())
    return loop, n, depth / max(width, 1e-300), lengths[k] / np.sqrt(area), ambiguous


def _mirror_plane(P, axis_of_rotation=None, *, steps: int = 60):
    """The plane of mirror symmetry through the samples' centroid: its unit normal and the
    mean mirror error (relative to the size).  With ``axis_of_rotation`` the plane contains that
    axis (the normal is searched in the orthogonal circle); else every direction of a
    hemisphere.  A coarse grid, then local refinement."""
    from scipy.spatial import cKDTree

    c = P.mean(0)
    X = P - c
    R = float(np.sqrt((X * X).sum(1).mean()))
    tree = cKDTree(X)
    sub = X[:: max(1, len(X) // 1500)]

    def err(a):
        a = _unit(a)
        return float(tree.query(sub - 2.0 * np.outer(sub @ a, a))[0].mean()) / R

    if axis_of_rotation is not None:
        ax = _unit(axis_of_rotation)
        e1 = _orthogonal(np.array([1.0, 0.0, 0.0]) if abs(ax[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), ax)
        e2 = np.cross(ax, e1)
        th = np.linspace(0, np.pi, steps, endpoint=False)
        errs = np.array([err(np.cos(t) * e1 + np.sin(t) * e2) for t in th])
        k = int(np.argmin(errs))
        t0, dt = th[k], np.pi / steps
        for _ in range(12):  # golden-section-like refinement
            cand = [t0 - dt / 2, t0, t0 + dt / 2]
            e = [err(np.cos(t) * e1 + np.sin(t) * e2) for t in cand]
            t0 = cand[int(np.argmin(e))]
            dt /= 2
        a = np.cos(t0) * e1 + np.sin(t0) * e2
        return _unit(a), err(a), float(np.median(errs))
    # hemisphere: a Fibonacci grid of directions, then local refinement on the sphere
    m = 200
    i = np.arange(m) + 0.5
    z = i / m
    phi = np.pi * (1 + 5 ** 0.5) * i
    D = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    errs = np.array([err(d) for d in D])
    best = D[int(np.argmin(errs))]
    step = 0.1
    cur = err(best)
    for _ in range(30):
        improved = False
        u = _orthogonal(np.array([1.0, 0.0, 0.0]) if abs(best[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), best)
        v = np.cross(best, u)
        for d in (u, -u, v, -v):
            cand = _unit(best + step * d)
            e = err(cand)
            if e < cur:
                best, cur, improved = cand, e, True
        if not improved:
            step /= 2
            if step < 1e-3:
                break
    return best, cur, float(np.median(errs))


def _detail(P, k: int = 24):
    """Surface variation of each sample's ``k`` nearest neighbours (0 on a plane or a large
    sphere; large at a nose, lips, eyelids)."""
    from scipy.spatial import cKDTree

    _, nb = cKDTree(P).query(P, k)
    Q = P[nb] - P[nb].mean(1, keepdims=True)
    ev = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", Q, Q))
    return ev[:, 0] / np.maximum(ev.sum(1), 1e-300)


def _nose_up(P, front, lateral):
    """The sign of up along ``front × lateral`` from the nose's profile: +1 / -1 and a margin in
    [0, 1] (0: no difference).  On the midline the most frontal sample is the nose tip; over a
    band of ``NOSE_BAND`` of the height below it the profile falls much further (to the upper
    lip) than over the same band above it (the bridge)."""
    a = _unit(np.cross(front, lateral))
    c = P.mean(0)
    X = P - c
    size = float(np.ptp(X @ a))
    mid = np.abs(X @ lateral) < 0.03 * size
    if mid.sum() < 30:
        return 0, 0.0, {}
    M = X[mid]
    z = M @ front
    tip = int(np.argmax(z))
    t = (M - M[tip]) @ a
    dz = z - z[tip]
    d = NOSE_BAND * size
    up_band = (t > 0.6 * d) & (t < 1.4 * d)
    down_band = (t < -0.6 * d) & (t > -1.4 * d)
    if up_band.sum() < 3 or down_band.sum() < 3:
        return 0, 0.0, {}
    fall_up = float(-dz[up_band].max())  # the frontmost surface at that height
    fall_down = float(-dz[down_band].max())
    margin = abs(fall_down - fall_up) / max(fall_down, fall_up, 1e-300)
    return (1 if fall_down > fall_up else -1), margin, {"nose_fall_above": fall_up / size, "nose_fall_below": fall_down / size}


def _flat_bottom(V, F, P, Pn, diag):
    """The largest flat region of the surface that lies on its convex hull (a cut): its outward
    normal and its share of the surface, or (None, 0)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(P)
    except QhullError:
        return None, 0.0, 0.0
    eq = hull.equations  # outward normals and offsets: n . x + d = 0
    tol = 2e-3 * diag
    best, share, second = None, 0.0, 0.0
    seen: list = []
    order = np.argsort(-_facet_areas(P, hull.simplices))
    for f in order[:200]:
        n, d = eq[f, :3], eq[f, 3]
        if any(abs(n @ m) > 0.996 and abs(d - e) < tol for m, e in seen):
            continue
        seen.append((n, d))
        on = (np.abs(P @ n + d) < tol) & (Pn @ n > 0.98)
        s = float(on.mean())
        if s > share:
            best, second, share = n, share, s
        elif s > second:
            second = s
    return best, share, second


def _facet_areas(P, simplices):
    A, B, C = P[simplices[:, 0]], P[simplices[:, 1]], P[simplices[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)


def _front_about(V, F, up):
    from ..mesh.frame import mesh_frame

    fr = mesh_frame(V, F, up=up)
    return fr.front, fr.how


def upright_frame(V, F, *, samples: int = 12000, seed: int = 0, fallback_up=(0.0, 1.0, 0.0),
                  snap: float = SNAP_DEGREES, whole=None) -> UprightFrame:
    """Up and front of the surface ``(V, F)`` — one clean component, as :func:`make_disk` has it
    after cleaning — from its shape (see the module's description).  An up (and then a front)
    within ``snap`` degrees of one of the file's axes is taken as that axis: scans are modelled
    along their axes, and a head whose up is the file's +Z should be cut level with it.
    ``whole``: ``(V, F)`` of every sizeable piece of the scan, where ``(V, F)`` is its largest:
    a standing figure's front is found on it."""
    fr = _upright_frame(V, F, samples, seed, fallback_up, whole)
    if snap <= 0:
        return fr
    up = _snapped(fr.up, snap)
    if up is fr.up:
        return fr
    front = _orthogonal(fr.front, up)
    front = _snapped(front, snap)
    if front @ up != 0.0:
        front = _orthogonal(front, up)
    return UprightFrame(up, front, fr.kind, fr.how + f"; snapped to the file's axes (within {snap:g}°)", fr.certain, fr.why,
                        dict(fr.cues, up_found=[float(x) for x in fr.up]), fr.template)


def _snapped(v, degrees):
    """``v`` replaced by the nearest signed axis when within ``degrees`` of it (else ``v`` itself)."""
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) >= np.cos(np.radians(degrees)):
        a = np.zeros(3)
        a[k] = np.sign(v[k])
        return a
    return v


def _upright_frame(V, F, samples, seed, fallback_up, whole=None) -> UprightFrame:
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    if len(F) == 0:
        raise GeofaceError("upright_frame: no faces")
    used = np.unique(F)
    diag = float(np.linalg.norm(np.ptp(V[used], 0)))
    P, Pn = surface_samples(V, F, samples, seed)
    Ps = P[:: max(1, samples // SCAN_POINTS)]
    op = _opening(V, F)
    cues: dict = {}
    kind = "closed"
    ambiguous = False
    if op is not None:
        _, n, depth_ratio, open_len, ambiguous = op
        cues.update(depth_ratio=depth_ratio, opening_length=open_len, opening_ambiguous=ambiguous)
        kind = "open at the neck" if depth_ratio >= FACE_DEPTH_RATIO else "face only"
    fit = fit_head_template(Ps, face_only=kind == "face only")
    if fit is not None:
        cues["template_fit"] = fit[3]
    if fit is not None and fit[3] <= TEMPLATE_FIT:
        how = f"the head template (fit {fit[3]:.3f})"
        turned = turned_fit(Ps, fit, face_only=kind == "face only")
        cues["template_fit_turned"] = turned[3]
        if turned[3] < TURNED_MARGIN * fit[3]:
            # it fits nearly as well with the face at the back: where the detail is decides
            up = _unit(fit[0] @ np.array([0.0, 1.0, 0.0]))
            detail, by = _front_about(V, F, up)
            if float(detail @ (turned[0] @ np.array([0.0, 0.0, 1.0]))) > float(detail @ (fit[0] @ np.array([0.0, 0.0, 1.0]))):
                fit = turned
            how += f"; either way round within {TURNED_MARGIN - 1:.0%}: the face by {by}"
        R = fit[0]
        up, front = _unit(R @ np.array([0.0, 1.0, 0.0])), _unit(R @ np.array([0.0, 0.0, 1.0]))
        if kind == "open at the neck" and up @ n < 0.5:  # the longest boundary is a hole, not the neck
            kind = "closed"
        return UprightFrame(up, front, kind, how, cues=cues, template=(fit[0], fit[1], fit[2], fit[3], kind == "face only"))
    fig = _standing_figure(Ps)
    if fig is not None and fig[1] <= FIGURE_FIT:
        up, fit_top, fit_bottom, sure, head_front = fig
        cues.update(figure_head_fit=fit_top, figure_foot_fit=fit_bottom)
        # the whole figure's front (its shoes, hands and hair are often pieces of their own, and
        # the feet are the cue); the template's front at a body's head end is too rough
        front, how = _front_about(*(whole if whole is not None else (V, F)), up)
        return UprightFrame(up, front, "figure", f"the long axis, towards the head (one piece, where the template fits); "
                            f"front by {how}", certain=sure, why="" if sure else "which end is the head is not clear",
                            cues=cues)
    if kind != "closed" and ambiguous:
        kind = "closed"  # not a head, and the longest loop is one hole among holes of its size
    if kind != "closed":
        # not a human head: up from the opening (a neck, or the open bottom of a shell)
        return _generic_open(V, F, n, cues)
    # closed and not a human head: a cut at the bottom, else the plane it rests on most stably
    nb, share, second = _flat_bottom(V, F, P, Pn, diag)
    cues.update(flat_share=share, flat_second=second)
    if nb is not None and share >= FLAT_SHARE and share >= 2.0 * second:
        up = -_unit(nb)
        front, how = _front_about(V, F, up)
        return UprightFrame(up, front, "closed", f"a flat cut at the bottom ({100 * share:.1f}% of the surface); front by {how}",
                            cues=cues)
    lateral, sym_err, sym_med = _mirror_plane(Ps)
    cues.update(symmetry_error=sym_err, symmetry_median=sym_med)
    rest = _resting_plane(P, diag, lateral if sym_err < 0.5 * sym_med else None)
    if rest is not None:
        nr, feet, margin, runner_up = rest
        cues.update(rest_contacts=feet, rest_margin=margin, rest_runner_up_contacts=runner_up)
        if margin > 0 and feet > runner_up:
            up = -_unit(nr)
            front, how = _front_about(V, F, up)
            return UprightFrame(up, front, "closed", f"the plane it stands on ({feet} separate contacts); front by {how}",
                                cues=cues)
    up = _unit(np.asarray(fallback_up, float))
    front, how = _front_about(V, F, up)
    return UprightFrame(up, front, "closed", f"the file's +Y; front by {how}", certain=False,
                        why="a closed surface that is not a human head, with no flat cut and no clear resting plane",
                        cues=cues)


def _generic_open(V, F, n, cues):
    front, how = _front_about(V, F, n)
    return UprightFrame(_unit(n), front, "open at the neck", f"the opening's normal; front by {how}", cues=cues)


def _resting_plane(P, diag, lateral=None):
    """The plane the shape stands on: among the convex hull's facet planes on which it is stable
    (its centroid projects inside the support polygon) and, for a mirror-symmetric shape, whose
    normal lies within 20° of the symmetry plane (``lateral``: its normal; a shape does not stand
    on its flank), the one touched in the most separate places (a quadruped's four feet, a
    table's legs), ties going to the larger stability margin.  (outward normal, contacts,
    margin relative to the size, the runner-up's contacts) or None."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    try:
        hull = ConvexHull(P)
    except QhullError:
        return None
    g = P.mean(0)
    tol = 0.01 * diag
    scored = []
    done: list = []
    for f in np.argsort(-_facet_areas(P, hull.simplices))[:300]:
        n, d = hull.equations[f, :3], hull.equations[f, 3]
        if any(n @ m > 0.995 for m in done):
            continue
        done.append(n)
        if lateral is not None and abs(n @ lateral) > np.sin(np.radians(20.0)):
            continue
        on = P[np.abs(P @ n + d) < tol]
        if len(on) < 3:
            continue
        e1 = _orthogonal(np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), n)
        e2 = np.cross(n, e1)
        Q = np.column_stack([on @ e1, on @ e2])
        c = np.array([g @ e1, g @ e2])
        try:
            poly = ConvexHull(Q)
        except QhullError:
            continue
        margin = float(-(poly.equations[:, :2] @ c + poly.equations[:, 2]).max()) / diag
        if margin <= 0:
            continue
        pairs = cKDTree(Q).query_pairs(0.05 * diag, output_type="ndarray")
        G = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(Q), len(Q)))
        contacts = int(connected_components(G, directed=False)[0])
        scored.append((contacts, margin, n))
    if not scored:
        return None
    scored.sort(key=lambda x: (-x[0], -x[1]))
    return scored[0][2], scored[0][0], scored[0][1], (scored[1][0] if len(scored) > 1 else 0)


def _standing_figure(P):
    """A standing figure (the longest principal extent over 2.2 times the next: a body, a
    statue): up along the long axis, towards its head: the end whose last tenth is one piece
    where the other is several (legs), else the end the head template fits better.
    (up, fit at the head end, fit at the other, certain, the template's front there) or None."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    c = P.mean(0)
    X = P - c
    w, E = np.linalg.eigh(X.T @ X)
    ext = np.array([np.ptp(X @ E[:, k]) for k in range(3)])
    order = np.argsort(ext)[::-1]
    if ext[order[0]] < 2.2 * ext[order[1]]:
        return None
    axis = E[:, order[0]]
    t = X @ axis
    fits, pieces, fronts = [], [], []
    for sgn in (1.0, -1.0):
        end = P[(sgn * t) >= (sgn * t).max() - 0.15 * np.ptp(t)]
        f = fit_head_template(end) if len(end) >= 100 else None
        fits.append(np.inf if f is None else f[3])
        fronts.append(None if f is None else f[0] @ np.array([0.0, 0.0, 1.0]))
        tip = P[(sgn * t) >= (sgn * t).max() - 0.10 * np.ptp(t)]
        G = cKDTree(tip).sparse_distance_matrix(cKDTree(tip), 0.04 * ext[order[0]], output_type="coo_matrix")
        pieces.append(int(connected_components(G, directed=False)[0]) if len(tip) else 0)
    if pieces[0] == 1 and pieces[1] >= 2:
        k, certain = 0, True
    elif pieces[1] == 1 and pieces[0] >= 2:
        k, certain = 1, True
    else:
        k = 0 if fits[0] <= fits[1] else 1
        certain = fits[k] <= 0.8 * fits[1 - k]
    up = axis if k == 0 else -axis
    return _unit(up), float(fits[k]), float(fits[1 - k]), certain, fronts[k]
