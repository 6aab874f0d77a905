"""Which way is up, and where is the front, of a head in any pose (``--up auto``).

Scans arrive Y-up (OBJ, glTF), Z-up facing +X (most scanning and acoustics software), Z-up
facing −Y (Blender), lying on their side, face up, turned any way, in any unit and far from the
origin. :func:`upright_frame` finds up and front so that the same head in any of these comes out
of ``geoface convert`` as the same images:

0. **The face, by looking.** The surface is rendered from all round and the face tracker looks
   for a face (:func:`geoface.track.scan.scan_landmarks`: its 68 landmarks lifted onto the
   surface, their median over several views). Where it finds one, up and front are the face's
   own (:func:`geoface.track.face3d.face_frame`), whatever the file's axes: no snapping. The cues
   below are checked against it, and ``how`` says which agree (``metrics.json`` keeps the angles).
   Where no face is seen (not a human head, a face-less bust, no MediaPipe) the cues decide:
1. **Open at the neck** (the longest boundary is a real opening, and the surface reaches far
   beyond it: deeper than 0.55 of the opening's width): up is the normal of the opening's
   plane, pointing into the surface.
2. **A face only** (the surface is shallow over its opening): front is the opening's normal.
3. **A human head** (the ICT-FaceKit head template registers to it): the template's up and front.
4. **Closed**: the bottom is where the head was cut — the largest flat region on the convex
   hull (a neck cap, a bust's base, a torso cut); failing that the plane it rests on most stably.

Without a face a frame is ``certain`` only when two cues agree (the template and the opening or
the flat cut; a cue and the plane of mirror symmetry through it); otherwise ``why`` says what was
unclear, for one line on the command line and for ``metrics.json``. An up (then a front) found
from the cues within :data:`SNAP_DEGREES` of a file axis is taken as that axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import GeofaceError, MissingDependencyError
from .cues import flat_bottom, mirror_plane, opening, orthogonal, resting_plane, standing_figure, unit
from .template import TEMPLATE_FIT, SCAN_POINTS, fit_head_template, fit_head_template_from, surface_samples  # noqa: F401
from .template import template_face_region, turned_fit

__all__ = ["UprightFrame", "upright_frame", "template_face_region", "FACE_DEPTH_RATIO", "SNAP_DEGREES", "AGREE_DEGREES"]

#: a surface shallower than this over its opening (depth / the opening's width) is a face only
FACE_DEPTH_RATIO = 0.55
#: the head template fitted half a turn about its up axis within this factor of the best fit: which
#: way the face looks is decided by the surface's detail (a smooth, egg-shaped head fits either way)
TURNED_MARGIN = 1.15
#: a standing figure's head end: the head template fits it closer than this (bodies 0.10-0.12,
#: the ends of a car 0.3)
FIGURE_FIT = 0.15
#: an up (then a front) found from the shape's cues this close to an axis of the file is taken as
#: that axis (degrees); a frame from the face is never snapped
SNAP_DEGREES = 15.0
#: a flat region must cover this share of the surface to be taken as the cut at the bottom
FLAT_SHARE = 0.01
#: two cues agree when their axes are this close (degrees)
AGREE_DEGREES = 20.0
#: a face only: its opening's normal agrees with the front this closely (a face scan's rim leans)
FACE_OPENING_DEGREES = 35.0
#: the head template registered from the face's landmarks fits closer than this: its face region
#: is the ROI (looser than :data:`TEMPLATE_FIT`, which tells a head from other shapes on its own)
FACE_TEMPLATE_FIT = 0.08


@dataclass(frozen=True)
class UprightFrame:
    """``up``, ``front`` (unit, orthogonal); ``kind``: "open at the neck", "face only", "closed" or
    "figure"; ``how``: the cues used; ``certain``: whether the face was found or the cues agreed
    (else ``why`` says what was unclear); ``cues``: the measured numbers, for reports; ``face``:
    the face found by looking (:class:`geoface.track.scan.ScanLandmarks`), or None."""

    up: np.ndarray
    front: np.ndarray
    kind: str
    how: str
    certain: bool = True
    why: str = ""
    cues: dict = field(default_factory=dict)
    template: tuple | None = field(default=None, repr=False)  # (R, s, t, fit, face only) of the head template
    face: object = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"up": [float(x) for x in self.up], "front": [float(x) for x in self.front], "kind": self.kind,
                "how": self.how, "certain": bool(self.certain), "why": self.why,
                "cues": {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in self.cues.items()}}


def _deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(float(unit(a) @ unit(b)), -1.0, 1.0))))


def _front_about(V, F, up):
    from ..mesh.frame import mesh_frame

    fr = mesh_frame(V, F, up=up)
    return fr.front, fr.how


def upright_frame(V, F, *, samples: int = 12000, seed: int = 0, fallback_up=(0.0, 1.0, 0.0),
                  snap: float = SNAP_DEGREES, whole=None, look: bool = True) -> UprightFrame:
    """Up and front of the surface ``(V, F)`` — one clean component, as :func:`make_disk` has it
    after cleaning — from its face, else from its shape (see the module's description).
    ``look``: look for the face (renders and MediaPipe; off: the shape's cues alone). A frame from
    the cues within ``snap`` degrees of one of the file's axes is taken as that axis. ``whole``:
    ``(V, F)`` of every sizeable piece of the scan, where ``(V, F)`` is its largest: a standing
    figure's front is found on it."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    if len(F) == 0:
        raise GeofaceError("upright_frame: no faces")
    face, note = None, ""
    if look:
        from ..track.scan import scan_landmarks

        try:
            face = scan_landmarks(V, F)
        except MissingDependencyError as e:
            note = f"no face finder ({e})"
    fr = _upright_frame(V, F, samples, seed, fallback_up, whole, face)
    if fr.face is not None and fr.face.found:
        return fr
    if note:
        fr = UprightFrame(fr.up, fr.front, fr.kind, fr.how + f"; {note}", fr.certain, fr.why, fr.cues, fr.template, face)
    if snap <= 0:
        return fr
    up = _snapped(fr.up, snap)
    if up is fr.up:
        return fr
    front = _snapped(orthogonal(fr.front, up), snap)
    if front @ up != 0.0:
        front = orthogonal(front, up)
    return UprightFrame(up, front, fr.kind, fr.how + f"; snapped to the file's axes (within {snap:g}°)", fr.certain, fr.why,
                        dict(fr.cues, up_found=[float(x) for x in fr.up]), fr.template, fr.face)


def _snapped(v, degrees):
    """``v`` replaced by the nearest signed axis when within ``degrees`` of it (else ``v`` itself)."""
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) >= np.cos(np.radians(degrees)):
        a = np.zeros(3)
        a[k] = np.sign(v[k])
        return a
    return v


def _from_face(V, F, Ps, face, op, kind, cues) -> UprightFrame:
    """The frame of the face found by looking, checked against the template and the opening."""
    up, front = unit(face.up), unit(face.front)
    cues.update(face_confidence=face.confidence, face_views=face.views, face_spread=face.spread,
                face_shape_error=face.shape_error, face_source=face.source, face_seconds=face.seconds,
                **{f"face_mirror_{k}": (float(v) if np.isfinite(v) else None)
                   for k, v in (("turn", face.mirror_turn), ("error", face.mirror_error))})
    found = f"{68 if face.source == 'face mesh' else 4} points"
    mirror = f"; yaw and roll from its mirror plane, {face.mirror_turn:.1f}°" if np.isfinite(face.mirror_turn) else ""
    checks = []
    points = face.points if face.source == "face mesh" else face.keypoints
    fit = fit_head_template_from(Ps, points, face_only=kind == "face only")
    template = None
    if fit is not None:
        cues["template_fit"] = fit[3]
        a = max(_deg(fit[0][:, 1], up), _deg(fit[0][:, 2], front))
        cues["template_angle"] = a
        if fit[3] <= FACE_TEMPLATE_FIT:
            template = (fit[0], fit[1], fit[2], fit[3], kind == "face only")
            checks.append(f"the head template {'agrees' if a <= AGREE_DEGREES else 'differs'} (fit {fit[3]:.3f}, {a:.0f}° apart)")
    if op is not None:
        n = op[1]
        if kind == "open at the neck":
            a = _deg(n, up)
            cues["opening_angle"] = a
            if up @ n < 0.5:  # the longest boundary is a hole, not the neck
                kind = "closed"
            else:
                checks.append(f"the neck opening {'agrees' if a <= AGREE_DEGREES else 'differs'} ({a:.0f}°)")
        elif kind == "face only":
            a = _deg(n, front)
            cues["opening_angle"] = a
            checks.append(f"the face's rim {'agrees' if a <= FACE_OPENING_DEGREES else 'differs'} ({a:.0f}°)")
    how = (f"the face ({found} from {face.views} views, score {face.confidence:.2f}, by the "
           f"{face.source}{mirror})" + (": " + ", ".join(checks) if checks else ""))
    fig = standing_figure(Ps)
    if fig is not None and fig[1] <= FIGURE_FIT and fig[0] @ up > np.cos(np.radians(45.0)):
        # a standing figure whose face was found: up is the body's (its feet are cut level), the
        # front the face's
        cues.update(figure_head_fit=fig[1], figure_foot_fit=fig[2], face_up_angle=_deg(fig[0], up))
        up = unit(fig[0])
        return UprightFrame(up, orthogonal(front, up), "figure", f"the long axis, towards the head; front by {how}",
                            cues=cues, template=template, face=face)
    return UprightFrame(up, front, kind, how, cues=cues, template=template, face=face)


def _upright_frame(V, F, samples, seed, fallback_up, whole=None, face=None) -> UprightFrame:
    used = np.unique(F)
    diag = float(np.linalg.norm(np.ptp(V[used], 0)))
    P, Pn = surface_samples(V, F, samples, seed)
    Ps = P[:: max(1, samples // SCAN_POINTS)]
    op = opening(V, F)
    cues: dict = {}
    kind = "closed"
    ambiguous = False
    if op is not None:
        _, n, depth_ratio, open_len, ambiguous = op
        cues.update(depth_ratio=depth_ratio, opening_length=open_len, opening_ambiguous=ambiguous)
        kind = "open at the neck" if depth_ratio >= FACE_DEPTH_RATIO else "face only"
    if face is not None and face.found:
        return _from_face(V, F, Ps, face, op, kind, cues)
    if face is not None:
        cues["face_not_found"] = face.why
    fit = fit_head_template(Ps, face_only=kind == "face only")
    if fit is not None:
        cues["template_fit"] = fit[3]
    if fit is not None and fit[3] <= TEMPLATE_FIT:
        how = f"the head template (fit {fit[3]:.3f})"
        turned = turned_fit(Ps, fit, face_only=kind == "face only")
        cues["template_fit_turned"] = turned[3]
        if turned[3] < TURNED_MARGIN * fit[3]:
            # it fits nearly as well with the face at the back: where the detail is decides
            up = unit(fit[0] @ np.array([0.0, 1.0, 0.0]))
            detail, by = _front_about(V, F, up)
            if float(detail @ (turned[0] @ np.array([0.0, 0.0, 1.0]))) > float(detail @ (fit[0] @ np.array([0.0, 0.0, 1.0]))):
                fit = turned
            how += f"; either way round within {TURNED_MARGIN - 1:.0%}: the face by {by}"
        R = fit[0]
        up, front = unit(R @ np.array([0.0, 1.0, 0.0])), unit(R @ np.array([0.0, 0.0, 1.0]))
        if kind == "open at the neck" and up @ n < 0.5:  # the longest boundary is a hole, not the neck
            kind = "closed"
        agree, by = _template_agrees(V, F, P, Pn, diag, op, kind, up, front, cues)
        how += f"; {by}" if by else ""
        why = "" if agree or face is None else f"no face was seen ({face.why}) and no other cue confirms the head template"
        return UprightFrame(up, front, kind, how, certain=not why, why=why, cues=cues,
                            template=(fit[0], fit[1], fit[2], fit[3], kind == "face only"), face=face)
    fig = standing_figure(Ps)
    if fig is not None and fig[1] <= FIGURE_FIT:
        up, fit_top, fit_bottom, sure, head_front = fig
        cues.update(figure_head_fit=fit_top, figure_foot_fit=fit_bottom)
        # the whole figure's front (its shoes, hands and hair are often pieces of their own, and
        # the feet are the cue); the template's front at a body's head end is too rough
        front, how = _front_about(*(whole if whole is not None else (V, F)), up)
        return UprightFrame(up, front, "figure", f"the long axis, towards the head (one piece, where the template fits); "
                            f"front by {how}", certain=sure, why="" if sure else "which end is the head is not clear",
                            cues=cues, face=face)
    if kind != "closed" and ambiguous:
        kind = "closed"  # not a head, and the longest loop is one hole among holes of its size
    if kind != "closed":
        # not a human head: up from the opening (a neck, or the open bottom of a shell)
        return _symmetric_about(V, F, Ps, unit(n), "open at the neck", "the opening's normal", cues, face)
    # closed and not a human head: a cut at the bottom, else the plane it rests on most stably
    nb, share, second = flat_bottom(V, F, P, Pn, diag)
    cues.update(flat_share=share, flat_second=second)
    if nb is not None and share >= FLAT_SHARE and share >= 2.0 * second:
        return _symmetric_about(V, F, Ps, -unit(nb), "closed", f"a flat cut at the bottom ({100 * share:.1f}% of the "
                                "surface)", cues, face)
    lateral, sym_err, sym_med = mirror_plane(Ps)
    cues.update(symmetry_error=sym_err, symmetry_median=sym_med)
    symmetric = sym_err < 0.5 * sym_med
    rest = resting_plane(P, diag, lateral if symmetric else None)
    if rest is not None:
        nr, feet, margin, runner_up = rest
        cues.update(rest_contacts=feet, rest_margin=margin, rest_runner_up_contacts=runner_up)
        if margin > 0 and feet > runner_up:
            up = -unit(nr)
            front, how = _front_about(V, F, up)
            # on a mirror-symmetric shape the plane it stands on was sought across the mirror plane
            return UprightFrame(up, front, "closed", f"the plane it stands on ({feet} separate contacts"
                                + ("; across its mirror plane" if symmetric else "") + f"); front by {how}",
                                certain=symmetric, why="" if symmetric else "no mirror plane confirms the plane it stands on",
                                cues=cues, face=face)
    up = unit(np.asarray(fallback_up, float))
    front, how = _front_about(V, F, up)
    return UprightFrame(up, front, "closed", f"the file's +Y; front by {how}", certain=False,
                        why="a closed surface that is not a human head, with no flat cut and no clear resting plane",
                        cues=cues, face=face)


def _template_agrees(V, F, P, Pn, diag, op, kind, up, front, cues):
    """Whether a cue other than the template confirms its frame: the neck opening's normal, a face
    scan's rim, a flat cut at the bottom. ``(agrees, what was found)``."""
    if op is not None and kind == "open at the neck":
        a = _deg(op[1], up)
        cues["opening_angle"] = a
        return a <= AGREE_DEGREES, f"the neck opening {'agrees' if a <= AGREE_DEGREES else 'differs'} ({a:.0f}°)"
    if op is not None and kind == "face only":
        a = _deg(op[1], front)
        cues["opening_angle"] = a
        return a <= FACE_OPENING_DEGREES, f"the face's rim {'agrees' if a <= FACE_OPENING_DEGREES else 'differs'} ({a:.0f}°)"
    nb, share, _ = flat_bottom(V, F, P, Pn, diag)
    if nb is not None and share >= FLAT_SHARE:
        a = _deg(-nb, up)
        cues["flat_angle"] = a
        return a <= AGREE_DEGREES, f"a flat cut {'agrees' if a <= AGREE_DEGREES else 'differs'} ({a:.0f}°)"
    return False, ""


def _symmetric_about(V, F, Ps, up, kind, what, cues, face) -> UprightFrame:
    """A frame whose up is one cue (an opening's normal, a flat cut): certain when the shape is
    mirror-symmetric about a plane through that up (the second cue)."""
    lateral, err, med = mirror_plane(Ps, up)
    cues.update(symmetry_error=err, symmetry_median=med)
    ok = err < 0.5 * med
    front, how = _front_about(V, F, up)
    return UprightFrame(up, front, kind, f"{what}" + ("; mirror-symmetric about it" if ok else "") + f"; front by {how}",
                        certain=ok, why="" if ok else f"{what} alone, not confirmed by a mirror plane through it",
                        cues=cues, face=face)
