"""A per-clip 3D head track with the ICT-FaceKit model, fitted to MediaPipe's dense landmarks.

What it fits, as the morphable-model trackers of the field do (metrical-tracker, VHAP): one
identity for the whole clip (the first ``n_identity`` ICT modes), per frame the 53 ARKit
expression weights (in [0, 1]) and a rigid pose, and one focal length — so that the ICT head's
points under MediaPipe's 468 face-mesh points project onto them.

Where each face-mesh point sits on the ICT head is a table that ships with geoface
(``geoface/data/mediapipe_ict.json``, built by ``data_tools/fit_mediapipe_ict.py`` on rendered
ICT-FaceKit people: a triangle of the model's face and barycentric weights per point, and a
confidence from how consistently MediaPipe puts the point there).

The objective, minimised over the whole clip at once by Levenberg–Marquardt with the Schur
complement on the shared unknowns, as bundle adjustment is (:mod:`geoface.track.head_solver`):

* data: a Cauchy (Lorentzian) loss of each point's reprojection error, scaled by the face's
  size in the frame (``scale`` × the distance between the face mesh's cheek points), weighted by the
  table's confidence; frames without a face have none;
* priors: identity weights N(0, 1) (``w_identity``), expression weights L1 towards 0
  (``w_expression``: sparse, as ARKit weights are) and within [0, 1], the focal length
  log-normal about its initial value (``w_focal``);
* temporal smoothness: squared differences of each frame's expressions, rotation and translation
  from its neighbours' (``w_smooth``; a video's frames are not independent photos).

MediaPipe's points slide over the face as it turns (the outline most): the table also holds, per
point, an offset on the head as a quadratic in the direction the camera sees the head from
(:func:`view_offsets`), fitted with the table.

It starts from OpenCV's PnP of the mean head on each frame (at the focal length given, or 1.2 ×
the image's larger side), first fits pose and focal alone, then everything. Rotations are
updates of the PnP rotation (axis-angle), so no parametrisation is near its singularity.

Coordinates: the ICT head in metres (y up, z out of the face), the camera OpenCV's (x right,
y down, z forward): ``x_cam = R X + t``, ``u = f x/z + cx``.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError
from geoface.track.head_solver import LM as _LM

__all__ = ["HeadTrack", "fit_head_track", "mediapipe_on_ict", "view_offsets", "TrackSettings", "CM_TO_M", "ICT_TRACK_PARTS",
           "neutral_head", "below_headset", "HEADSET_CUT"]

log = logging.getLogger(__name__)

CM_TO_M = 0.01
#: the parts of the ICT model the tracked head has (the same as the avatars' ICT person)
ICT_TRACK_PARTS = ("skin", "eyes", "teeth", "mouth")
_TABLE = Path(__file__).parents[1] / "data" / "mediapipe_ict.json"
#: MediaPipe face-mesh indices of the cheeks' outermost points (the face's width in a frame)
CHEEKS = (234, 454)


@lru_cache(maxsize=1)
def mediapipe_on_ict() -> dict:
    """The table (module doc): ``vertices`` (468, 3) indices into the ICT head of
    :data:`ICT_TRACK_PARTS`, ``weights`` (468, 3) barycentric, ``confidence`` (468,) in (0, 1]."""
    d = json.loads(_TABLE.read_text())
    out = {"vertices": np.asarray(d["vertices"], np.int64), "weights": np.asarray(d["weights"], np.float64),
           "confidence": np.asarray(d["confidence"], np.float64), "model_vertices": int(d["model_vertices"]),
           "view_offsets": np.asarray(d.get("view_offsets_cm", np.zeros((468, 5, 3))), np.float64) * CM_TO_M}
    if (out["vertices"].shape != (468, 3) or out["weights"].shape != (468, 3) or out["confidence"].shape != (468,)
            or out["view_offsets"].shape != (468, 5, 3)):
        raise GeofaceError(f"{_TABLE}: malformed MediaPipe→ICT table")
    return out


@dataclass(frozen=True)
class TrackSettings:
    """The fit's knobs (module doc); the defaults were tried on the rendered validation person of
    ``bench/bench_head_track.py`` (person 11)."""

    n_identity: int = 40
    iterations: int = 30
    rigid_iterations: int = 10
    scale: float = 0.01          # Cauchy scale, in face widths (about 2 px on a 200 px face)
    w_identity: float = 1e-4
    w_expression: float = 2e-3
    w_focal: float = 1e-2
    w_smooth: float = 2.0


@dataclass(frozen=True)
class HeadTrack:
    """A fitted clip. ``identity (n_identity,)``, ``expressions (T, 53)`` (order
    ``expression_names``), ``R (T, 3, 3)`` and ``t (T, 3)`` head → camera (metres), ``focal`` and
    ``centre`` (pixels), ``image_size`` (W, H), ``found (T,)``, ``residual_px (T,)`` each frame's
    median reprojection error over the points it was fitted to, ``seconds`` the fit's time."""

    identity: np.ndarray
    expressions: np.ndarray
    expression_names: tuple
    R: np.ndarray
    t: np.ndarray
    focal: float
    centre: tuple
    image_size: tuple
    found: np.ndarray
    residual_px: np.ndarray
    seconds: float = 0.0
    settings: TrackSettings = field(default_factory=TrackSettings)

    def __len__(self) -> int:
        return len(self.R)

    def camera(self):
        """The fixed camera the track is seen through (world = camera coordinates)."""
        from geoface.camera import Camera

        W, H = self.image_size
        return Camera(self.focal, self.focal, self.centre[0], self.centre[1], W, H, np.eye(3), np.zeros(3))

    @cached_property
    def _neutral(self) -> np.ndarray:
        return neutral_head(self.identity)  # made once per track: the posed heads of every frame share it

    def neutral(self) -> np.ndarray:
        """The person's expressionless head (metres, canonical), vertices of :data:`ICT_TRACK_PARTS`."""
        return self._neutral.copy()

    def canonical(self, frame: int) -> np.ndarray:
        """Frame ``frame``'s head with its expression, canonical pose (metres)."""
        v = model_view()
        return self._neutral + np.tensordot(self.expressions[frame], v.expression_modes, axes=1) * CM_TO_M

    def posed(self, frame: int) -> np.ndarray:
        """Frame ``frame``'s head in camera coordinates (metres)."""
        return self.canonical(frame) @ self.R[frame].T + self.t[frame]

    def points(self, frame: int | None = None) -> np.ndarray:
        """The 468 face-mesh points projected, ``(T, 468, 2)`` (or one frame's ``(468, 2)``)."""
        P = _point_basis(self)
        frames = range(len(self)) if frame is None else [frame]
        out = []
        for f in frames:
            X = P[f] @ self.R[f].T + self.t[f]
            out.append(np.stack([self.focal * X[:, 0] / X[:, 2] + self.centre[0],
                                 self.focal * X[:, 1] / X[:, 2] + self.centre[1]], 1))
        return np.stack(out) if frame is None else out[0]


def model_view():
    from geoface.synth.ict import load_ict_model

    return load_ict_model().view(ICT_TRACK_PARTS)


def neutral_head(identity, view=None) -> np.ndarray:
    """The ICT head of ``identity`` (weights of the first ``len(identity)`` modes) without
    expression, in metres, canonical: the vertices of ``view`` (an ICT model view; default the
    track's, :data:`ICT_TRACK_PARTS`)."""
    v = model_view() if view is None else view
    a = np.asarray(identity, np.float64)
    return (v.neutral + np.tensordot(a, v.identity_modes[: len(a)], axes=1)) * CM_TO_M


#: where a headset's lower edge sits on the face: this share of the way down from the eyes' corners
#: to the nose tip, less 5 mm (metres) for the visor's rim (:func:`below_headset`)
HEADSET_CUT = (0.4, 0.005)


def below_headset(identity) -> tuple[np.ndarray, np.ndarray]:
    """What a headset leaves visible of the head of ``identity``: ``(points (468,) bool, vertices
    (n,) bool)``, MediaPipe's face-mesh points and the head's vertices (:data:`ICT_TRACK_PARTS`)
    below the cut of :data:`HEADSET_CUT` (canonical heights: a level line across the face). For
    :func:`fit_head_track`'s ``use`` and :func:`geoface.track.head_refine.refine_photometric`'s
    ``region`` on frames where the upper face is hidden."""
    mean, Bid, _ = point_bases()
    a = np.asarray(identity, np.float64)
    P = mean + np.tensordot(a, Bid[: len(a)], axes=1)
    y_eye, y_nose = P[[33, 133, 362, 263], 1].mean(), P[1, 1]
    cut = y_eye - HEADSET_CUT[0] * (y_eye - y_nose) - HEADSET_CUT[1]
    return P[:, 1] < cut, neutral_head(a)[:, 1] < cut


@lru_cache(maxsize=1)
def point_bases():
    """(mean (468, 3), identity (100, 468, 3), expression (53, 468, 3)) at the table's points, metres."""

    v = model_view()
    tab = mediapipe_on_ict()
    if tab["model_vertices"] != len(v.neutral):
        raise GeofaceError(f"{_TABLE}: made for an ICT head of {tab['model_vertices']} vertices; this one has "
                           f"{len(v.neutral)}")
    idx, w = tab["vertices"], tab["weights"]

    def at(A):  # (..., n, 3) → (..., 468, 3)
        return np.einsum("...kjd,kj->...kd", A[..., idx, :], w) * CM_TO_M

    return at(v.neutral), at(v.identity_modes.astype(np.float64)), at(v.expression_modes.astype(np.float64))


def view_offsets(R, t, centre) -> np.ndarray:
    """Where MediaPipe's points sit on a head seen from a side differs from where they sit on a
    frontal one (its points slide over the face as it turns, the outline most): the table's
    offsets (canonical metres, ``(T, 468, 3)``) for heads posed ``R (T, 3, 3)``, ``t (T, 3)``
    (head → camera), as a quadratic in the direction to the camera in the head's frame; the head's
    ``centre`` (canonical) is where that direction is taken from."""
    C = mediapipe_on_ict()["view_offsets"]
    eye = -np.einsum("tji,tj->ti", R, t)  # the camera's centre in head coordinates
    d = eye - centre
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    phi = np.stack([d[:, 0], d[:, 1], d[:, 0] ** 2, d[:, 1] ** 2, d[:, 0] * d[:, 1]], 1)
    return np.einsum("tf,kfd->tkd", phi, C)


def _point_basis(track: HeadTrack) -> np.ndarray:
    mean, Bid, Bex = point_bases()
    a = np.asarray(track.identity, np.float64)
    base = mean + np.tensordot(a, Bid[: len(a)], axes=1)
    return (base[None] + np.einsum("te,ekd->tkd", track.expressions, Bex)
            + view_offsets(track.R, track.t, mean.mean(0)))


def pnp(P3, p2, focal, centre):
    """OpenCV's PnP: (R, t) of ``P3`` seen at ``p2``; None where it fails."""
    import cv2

    K = np.array([[focal, 0, centre[0]], [0, focal, centre[1]], [0, 0, 1.0]])
    ok, rv, tv = cv2.solvePnP(P3.astype(np.float64), p2.astype(np.float64), K, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return None
    ok, rv, tv = cv2.solvePnP(P3.astype(np.float64), p2.astype(np.float64), K, None, rv, tv, True,
                              flags=cv2.SOLVEPNP_ITERATIVE)
    R, _ = cv2.Rodrigues(rv)
    return (R, tv.ravel()) if ok and tv.ravel()[2] > 0 else None


def fit_head_track(points, image_size, *, found=None, focal: float | None = None, focal_init: float | None = None, use=None,
                   identity=None, settings: TrackSettings | None = None, quiet: bool | None = None) -> HeadTrack:
    """Fit the ICT head to a clip's face-mesh points ``points (T, 468, 2)`` (pixels; NaN rows
    where no face was found) in images of ``image_size`` (W, H). ``focal``: the camera's focal
    length in pixels when known (then fixed), else estimated, starting at ``focal_init`` (default
    1.2 × the larger side: a phone's or a webcam's field of view) with a log-normal prior about it.
    ``use``: a bool (468,) of the points to fit (the others are held out, e.g. to measure the fit
    on points it did not see). ``identity``: the person's identity weights when known (another
    clip's track of the same person, ``HeadTrack.identity``): the head is then held as it is, and
    only expressions, poses and the focal length are fitted. Returns a :class:`HeadTrack`."""
    import time

    from geoface.progress import StepProgress

    s = settings or TrackSettings()
    P = np.asarray(points, np.float64)
    if P.ndim != 3 or P.shape[1:] != (468, 2):
        raise GeofaceError(f"head track: points must be (T, 468, 2) face-mesh points; got {P.shape}")
    W, H = (int(x) for x in image_size)
    if W < 8 or H < 8:
        raise GeofaceError(f"head track: image size must be at least 8×8; got {W}×{H}")
    ok = np.isfinite(P).all((1, 2)) if found is None else np.asarray(found, bool) & np.isfinite(P).all((1, 2))
    if not ok.any():
        raise GeofaceError(f"head track: no face in any of the {len(P)} frames")
    if focal is not None and not (np.isfinite(focal) and focal > 0):
        raise GeofaceError(f"head track: focal must be a positive number of pixels; got {focal!r}")
    use = np.ones(468, bool) if use is None else np.asarray(use, bool)
    if use.shape != (468,) or use.sum() < 20:
        raise GeofaceError("head track: use must be a bool (468,) choosing at least 20 points")
    t0 = time.perf_counter()
    T = len(P)
    centre = (W / 2.0, H / 2.0)
    if focal_init is not None and not (np.isfinite(focal_init) and focal_init > 0):
        raise GeofaceError(f"head track: focal_init must be a positive number of pixels; got {focal_init!r}")
    f0 = float(focal) if focal is not None else float(focal_init or 1.2 * max(W, H))
    mean, Bid, Bex = point_bases()
    n_id = int(min(max(s.n_identity, 0), len(Bid)))
    held = None
    if identity is not None:
        held = np.asarray(identity, np.float64).reshape(-1)
        if len(held) > len(Bid) or not np.isfinite(held).all():
            raise GeofaceError(f"head track: identity must be at most {len(Bid)} finite weights; got {len(held)}")
        mean, n_id = mean + np.tensordot(held, Bid[: len(held)], axes=1), 0  # the person's head, not fitted
    conf = mediapipe_on_ict()["confidence"] * use
    # PnP on each frame with a face; the others take the nearest found frame's pose
    R0, t0v = np.zeros((T, 3, 3)), np.zeros((T, 3))
    good = np.zeros(T, bool)
    for k in np.flatnonzero(ok):
        r = pnp(mean[use], P[k, use], f0, centre)
        if r is not None:
            R0[k], t0v[k] = r
            good[k] = True
    if not good.any():
        raise GeofaceError("head track: no frame's landmarks give a head pose (PnP failed on all)")
    gi = np.flatnonzero(good)
    for k in np.flatnonzero(~good):
        j = gi[np.argmin(np.abs(gi - k))]
        R0[k], t0v[k] = R0[j], t0v[j]
    ok &= good
    width = np.linalg.norm(P[:, CHEEKS[0]] - P[:, CHEEKS[1]], axis=-1)
    width = np.where(ok, width, np.nanmedian(width[ok]))

    lm = _LM(P, ok, use, conf, width, f0, centre, R0, t0v, mean, Bid[:n_id], Bex, s, estimate_focal=focal is None,
             offsets=view_offsets)
    bar = StepProgress(s.rigid_iterations + s.iterations, "fitting the head", quiet=quiet)
    try:
        lm.run(s.rigid_iterations, full=False, bar=bar)
        lm.run(s.iterations, full=True, bar=bar)
    finally:
        bar.close()
    uv = lm.project(lm.state)[2]
    err = np.linalg.norm(uv - np.nan_to_num(P), axis=-1)
    err = np.where(ok[:, None] & use[None], err, np.nan)
    resid = np.full(T, np.nan)
    resid[ok] = np.nanmedian(err[ok], axis=1)
    a, logf, E, R, t = lm.state
    return HeadTrack(identity=a.copy() if held is None else held.copy(), expressions=E.copy(), expression_names=tuple(_model_names()), R=R.copy(),
                     t=t.copy(), focal=float(f0 * np.exp(logf)), centre=centre, image_size=(W, H), found=ok,
                     residual_px=resid, seconds=time.perf_counter() - t0, settings=s)


def _model_names():
    from geoface.synth.ict import load_ict_model

    return load_ict_model().expression_names
