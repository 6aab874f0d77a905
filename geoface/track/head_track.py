"""A per-clip 3D head track with the ICT-FaceKit model, fitted to MediaPipe's dense landmarks.

What it fits, as the morphable-model trackers of the field do (metrical-tracker, VHAP): one
identity for the whole clip (the first ``n_identity`` ICT modes), per frame the 53 ARKit
expression weights (in [0, 1]) and a rigid pose, and one focal length — so that the ICT head's
points under MediaPipe's 468 face-mesh points project onto them.

Where each face-mesh point sits on the ICT head is a table that ships with geoface
(``geoface/data/mediapipe_ict.json``, built by ``data_tools/fit_mediapipe_ict.py`` on rendered
ICT-FaceKit people: a triangle of the model's face and barycentric weights per point, and a
confidence from how consistently MediaPipe puts the point there).

The objective, minimised by Adam over the whole clip at once (torch, float64):

* data: a Cauchy (Lorentzian) loss of each point's reprojection error, scaled by the face's
  size in the frame (``scale`` × the distance between the face mesh's cheek points), weighted by the
  table's confidence; frames without a face have none;
* priors: identity weights N(0, 1) (``w_identity``), expression weights L1 towards 0
  (``w_expression``: sparse, as ARKit weights are), the focal length log-normal about its
  initial value (``w_focal``);
* temporal smoothness: squared frame-to-frame differences of expressions, rotations and
  translations (``w_smooth``; a video's frames are not independent photos).

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
from functools import lru_cache
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["HeadTrack", "fit_head_track", "mediapipe_on_ict", "TrackSettings", "CM_TO_M", "ICT_TRACK_PARTS"]

log = logging.getLogger(__name__)

CM_TO_M = 0.01
#: the parts of the ICT model the tracked head has (the same as the avatars' ICT person)
ICT_TRACK_PARTS = ("skin", "eyes", "teeth", "mouth")
_TABLE = Path(__file__).parents[1] / "data" / "mediapipe_ict.json"
#: MediaPipe face-mesh indices of the cheeks' outermost points (the face's width in a frame)
_CHEEKS = (234, 454)


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
    """The fit's knobs (module doc); the defaults were chosen on rendered validation people
    (``bench/bench_head_track.py``)."""

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

    def neutral(self) -> np.ndarray:
        """The person's expressionless head (metres, canonical), vertices of :data:`ICT_TRACK_PARTS`."""
        v = _model_view()
        a = np.asarray(self.identity, np.float64)
        return (v.neutral + np.tensordot(a, v.identity_modes[: len(a)], axes=1)) * CM_TO_M

    def canonical(self, frame: int) -> np.ndarray:
        """Frame ``frame``'s head with its expression, canonical pose (metres)."""
        v = _model_view()
        return self.neutral() + np.tensordot(self.expressions[frame], v.expression_modes, axes=1) * CM_TO_M

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


def _model_view():
    from geoface.synth.ict import load_ict_model

    return load_ict_model().view(ICT_TRACK_PARTS)


@lru_cache(maxsize=1)
def _bases():
    """(mean (468, 3), identity (100, 468, 3), expression (53, 468, 3)) at the table's points, metres."""

    v = _model_view()
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
    mean, Bid, Bex = _bases()
    a = np.asarray(track.identity, np.float64)
    base = mean + np.tensordot(a, Bid[: len(a)], axes=1)
    return (base[None] + np.einsum("te,ekd->tkd", track.expressions, Bex)
            + view_offsets(track.R, track.t, mean.mean(0)))


def _pnp(P3, p2, focal, centre):
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
                   settings: TrackSettings | None = None, quiet: bool | None = None) -> HeadTrack:
    """Fit the ICT head to a clip's face-mesh points ``points (T, 468, 2)`` (pixels; NaN rows
    where no face was found) in images of ``image_size`` (W, H). ``focal``: the camera's focal
    length in pixels when known (then fixed), else estimated, starting at ``focal_init`` (default
    1.2 × the larger side: a phone's or a webcam's field of view) with a log-normal prior about it.
    ``use``: a bool (468,) of the points to fit (the others are held out, e.g. to measure the fit
    on points it did not see). Returns a :class:`HeadTrack`."""
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
    mean, Bid, Bex = _bases()
    n_id = int(min(max(s.n_identity, 0), len(Bid)))
    conf = mediapipe_on_ict()["confidence"] * use
    # PnP on each frame with a face; the others take the nearest found frame's pose
    R0, t0v = np.zeros((T, 3, 3)), np.zeros((T, 3))
    good = np.zeros(T, bool)
    for k in np.flatnonzero(ok):
        r = _pnp(mean[use], P[k, use], f0, centre)
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
    width = np.linalg.norm(P[:, _CHEEKS[0]] - P[:, _CHEEKS[1]], axis=-1)
    width = np.where(ok, width, np.nanmedian(width[ok]))

    lm = _LM(P, ok, use, conf, width, f0, centre, R0, t0v, mean, Bid[:n_id], Bex, s, estimate_focal=focal is None)
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
    return HeadTrack(identity=a.copy(), expressions=E.copy(), expression_names=tuple(_model_names()), R=R.copy(),
                     t=t.copy(), focal=float(f0 * np.exp(logf)), centre=centre, image_size=(W, H), found=ok,
                     residual_px=resid, seconds=time.perf_counter() - t0, settings=s)


def _skew(v):
    """(..., 3) → (..., 3, 3) cross-product matrices."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _expmap(w):
    """(T, 3) rotation vectors → (T, 3, 3) (Rodrigues)."""
    th = np.linalg.norm(w, axis=-1)[:, None, None]
    K = _skew(w / np.maximum(th[..., 0], 1e-15))
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)


def _logmap(R):
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


class _LM:
    """Levenberg–Marquardt over the clip, as in bundle adjustment: per frame a block of 59
    unknowns (rotation update, translation, 53 expression weights), shared by all frames the
    identity weights and the focal length's logarithm; each step solves the normal equations by
    the Schur complement on the shared block (frames are independent given it). The Cauchy loss
    by iteratively reweighted least squares; the expression bounds by projection; the temporal
    smoothness pulls each frame towards the mean of its neighbours at the current iterate."""

    NF = 59

    def __init__(self, P, ok, use, conf, width, f0, centre, R0, t0, mean, Bid, Bex, s, *, estimate_focal):
        self.P, self.ok, self.s = np.nan_to_num(P), ok, s
        self.f0, self.c = f0, np.asarray(centre, np.float64)
        self.mean, self.Bid, self.Bex = mean, Bid, Bex
        self.nid, self.ne = len(Bid), len(Bex)
        self.est_f = estimate_focal
        self.Wpt = ok[:, None] * (conf * use)[None]  # (T, K)
        self.norm = max(float(self.Wpt.sum()), 1e-9)
        self.sc2 = (s.scale * width) ** 2  # (T,)
        self.depth = float(np.median(t0[ok, 2]))
        T = len(P)
        self.state = (np.zeros(self.nid), 0.0, np.zeros((T, self.ne)), R0.copy(), t0.copy())
        self.lam = 1e-3

    def project(self, st):
        a, logf, E, R, t = st
        X = ((self.mean + np.tensordot(a, self.Bid, axes=1))[None] + np.einsum("te,ekd->tkd", E, self.Bex)
             + view_offsets(R, t, self.mean.mean(0)))
        Xc = np.einsum("tij,tkj->tki", R, X) + t[:, None]
        z = np.maximum(Xc[..., 2], 1e-6)
        f = self.f0 * np.exp(logf)
        return X, Xc, f * Xc[..., :2] / z[..., None] + self.c

    def _neighbours(self, A):
        """The mean of each frame's neighbours (one neighbour at the ends)."""
        out = np.empty_like(A)
        if len(A) == 1:
            return A.copy()
        out[1:-1] = 0.5 * (A[:-2] + A[2:])
        out[0], out[-1] = A[1], A[-2]
        return out

    def cost(self, st, full):
        a, logf, E, R, t = st
        _, _, uv = self.project(st)
        s2 = ((uv - self.P) ** 2).sum(-1) / self.sc2[:, None]
        c = float((self.Wpt * np.log1p(s2)).sum()) / self.norm
        s, T = self.s, len(E)
        c += s.w_focal * logf ** 2
        ws = s.w_smooth / T
        Rn = self._neighbours_rot(R)
        c += ws * float((_logmap(np.einsum("tij,tkj->tik", R, Rn)) ** 2).sum())
        c += ws * float((((t - self._neighbours(t)) / self.depth) ** 2).sum())
        if full:
            c += s.w_identity * float(a @ a) + s.w_expression * float(E.sum()) / T
            c += ws * float(((E - self._neighbours(E)) ** 2).sum())
        return c

    def _neighbours_rot(self, R):
        from scipy.spatial.transform import Rotation

        if len(R) == 1:
            return R.copy()
        q = Rotation.from_matrix(R).as_quat()
        q = q * np.sign((q * q[np.r_[0, np.arange(len(q) - 1)]]).sum(1))[:, None]  # one hemisphere
        qs = self._neighbours(q)
        return Rotation.from_quat(qs / np.linalg.norm(qs, axis=1, keepdims=True)).as_matrix()

    def step_system(self, st, full):
        """Normal equations: (H_ff (T, 59, 59), H_fs (T, 59, S), H_ss (S, S), g_f (T, 59), g_s (S,))."""
        a, logf, E, R, t = st
        s, T, K = self.s, len(E), self.P.shape[1]
        S = self.nid + 1
        X, Xc, uv = self.project(st)
        r = uv - self.P  # (T, K, 2)
        s2 = (r ** 2).sum(-1) / self.sc2[:, None]
        w = 2 * self.Wpt / (1 + s2) / self.sc2[:, None] / self.norm  # IRLS weights (T, K)
        f = self.f0 * np.exp(logf)
        z = np.maximum(Xc[..., 2], 1e-6)
        A = np.zeros((T, K, 2, 3))
        A[..., 0, 0] = A[..., 1, 1] = f / z
        A[..., 0, 2] = -f * Xc[..., 0] / z ** 2
        A[..., 1, 2] = -f * Xc[..., 1] / z ** 2
        Hff = np.zeros((T, self.NF, self.NF))
        Hfs = np.zeros((T, self.NF, S))
        Hss = np.zeros((S, S))
        gf = np.zeros((T, self.NF))
        gs = np.zeros(S)
        RX = Xc - t[:, None]
        for lo in range(0, T, 16):  # frames in chunks (the Jacobians are 468 × 2 × 160 per frame)
            sl = slice(lo, min(lo + 16, T))
            Ac = A[sl]
            n = Ac.shape[0]
            RBe = np.einsum("tjl,ekl->tkje", R[sl], self.Bex, optimize=True)  # (n, K, 3, 53)
            RBi = np.einsum("tjl,ekl->tkje", R[sl], self.Bid, optimize=True)  # (n, K, 3, nid)
            J = np.empty((n, K, 2, self.NF + S))
            J[..., 0:3] = -Ac @ _skew(RX[sl])
            J[..., 3:6] = Ac
            J[..., 6:self.NF] = Ac @ RBe
            J[..., self.NF:self.NF + self.nid] = Ac @ RBi
            J[..., -1] = uv[sl] - self.c
            J = J.reshape(n, 2 * K, self.NF + S)
            wr = np.repeat(w[sl], 2, axis=1)  # (n, 2K)
            Jw = J * wr[..., None]
            H = Jw.transpose(0, 2, 1) @ J  # (n, 59 + S, 59 + S)
            g = np.einsum("tra,tr->ta", Jw, r[sl].reshape(n, 2 * K))
            Hff[sl] = H[:, :self.NF, :self.NF]
            Hfs[sl] = H[:, :self.NF, self.NF:]
            Hss += H[:, self.NF:, self.NF:].sum(0)
            gf[sl] = g[:, :self.NF]
            gs += g[:, self.NF:].sum(0)
        ws = 2 * s.w_smooth / T
        # smoothness towards the neighbours' mean (the neighbours held at the current iterate)
        dr = _logmap(np.einsum("tij,tkj->tik", R, self._neighbours_rot(R)))
        gf[:, 0:3] += ws * dr
        gf[:, 3:6] += ws * (t - self._neighbours(t)) / self.depth ** 2
        idx = np.arange(6)
        Hff[:, idx[:3], idx[:3]] += ws
        Hff[:, idx[3:], idx[3:]] += ws / self.depth ** 2
        gs[self.nid] += 2 * s.w_focal * logf
        Hss[self.nid, self.nid] += 2 * s.w_focal
        if full:
            gf[:, 6:] += s.w_expression / T + ws * (E - self._neighbours(E))
            Hff[:, np.arange(6, self.NF), np.arange(6, self.NF)] += ws
            gs[:self.nid] += 2 * s.w_identity * a
            Hss[np.arange(self.nid), np.arange(self.nid)] += 2 * s.w_identity
        return Hff, Hfs, Hss, gf, gs

    def solve(self, sys_, full):
        Hff, Hfs, Hss, gf, gs = (x.copy() for x in sys_)
        active_f = np.ones(self.NF, bool)
        active_s = np.ones(len(gs), bool)
        if not full:
            active_f[6:] = False
            active_s[:self.nid] = False
        if not self.est_f:
            active_s[self.nid] = False
        for H, g, act in ((Hff, gf, active_f), (None, None, None)):
            if H is None:
                break
            H[:, ~act, :] = 0
            H[:, :, ~act] = 0
            H[:, ~act, ~act] = 1
            g[:, ~act] = 0
        Hfs[:, ~active_f, :] = 0
        Hfs[:, :, ~active_s] = 0
        Hss[~active_s, :] = 0
        Hss[:, ~active_s] = 0
        Hss[~active_s, ~active_s] = 1
        gs[~active_s] = 0
        d = np.arange(self.NF)
        Hff[:, d, d] += self.lam * Hff[:, d, d] + 1e-12
        ds = np.arange(len(gs))
        Hss[ds, ds] += self.lam * Hss[ds, ds] + 1e-12
        Y = np.linalg.solve(Hff, np.concatenate([Hfs, gf[..., None]], -1))  # H_ff⁻¹ [H_fs | g_f]
        Sc = Hss - np.einsum("tfa,tfb->ab", Hfs, Y[..., :-1])
        rhs = -gs + np.einsum("tfa,tf->a", Hfs, Y[..., -1])
        xs = np.linalg.solve(Sc, rhs)
        xf = -Y[..., -1] - np.einsum("tfa,a->tf", Y[..., :-1], xs)
        return xf, xs

    def apply(self, st, xf, xs):
        a, logf, E, R, t = st
        return (a + xs[:self.nid], logf + float(xs[self.nid]), np.clip(E + xf[:, 6:], 0.0, 1.0),
                _expmap(xf[:, :3]) @ R, t + xf[:, 3:6])

    def run(self, iterations: int, *, full: bool, bar) -> None:
        c = self.cost(self.state, full)
        done = 0
        while done < iterations:
            sys_ = self.step_system(self.state, full)
            for _ in range(8):
                xf, xs = self.solve(sys_, full)
                cand = self.apply(self.state, xf, xs)
                cc = self.cost(cand, full)
                done += 1
                bar.update(1)
                if cc < c:
                    self.lam = max(self.lam / 3, 1e-7)
                    break
                self.lam = min(self.lam * 5, 1e7)
            else:
                bar.update(max(iterations - done, 0))
                return
            improved = c - cc
            self.state, c = cand, cc
            if improved < 1e-9 * max(c, 1e-12):
                bar.update(max(iterations - done, 0))
                return


def _model_names():
    from geoface.synth.ict import load_ict_model

    return load_ict_model().expression_names
