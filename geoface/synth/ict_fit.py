"""Fit the ICT-FaceKit model to 68 face landmarks in a photo: identity, expression, head pose
and a pinhole camera, so that a photo needs no mesh or camera of its own (the skin-texture
reconstruction projects the photo into the fitted head's UV layout).

Landmarks are the 68 points of the Multi-PIE layout that dlib, face-alignment, MediaPipe's 68
subset and most trackers write, in pixels (x right, y down, origin at the top-left corner of the
image). A landmarks file (:func:`load_landmarks`) is

* JSON: ``{"image_size": [W, H], "landmarks": [[x, y], ... 68 pairs]}`` (``image_size``
  optional; the points may also be the whole document, a list of 68 pairs);
* ``.npy``: a ``(68, 2)`` array; ``.txt`` / ``.pts``: 68 lines ``x y`` (a ``.pts`` file's
  ``{`` ``}`` header lines are skipped).

The fit (:func:`fit_landmarks`) is a robust non-linear least squares (SciPy's trust-region
reflective method, Huber loss at 1 px) over the rotation (axis-angle), the translation, the
focal length (log, with a weak prior), the first ``n_identity`` identity weights (prior
N(0, 1)) and the 53 expression weights (in [0, 1], an L2 prior pulling them to 0). It starts from
the mean head posed by OpenCV's PnP at a focal length of 1.2 × the image's larger side. The
17 jaw-contour landmarks are weighted 0.5: detectors put them on the silhouette, which slides
over the surface as the head turns, while the model pins them to vertices. The camera is OpenCV's:
``x_cam = R X + t`` in centimetres, looking down +z, ``u = f x/z + cx``, ``v = f y/z + cy``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import GeofaceError

__all__ = ["LandmarkFit", "fit_landmarks", "heldout_errors", "load_landmarks", "project", "JAW"]

#: the jaw-contour landmarks of the 68-point layout (weighted 0.5 in the fit)
JAW = np.arange(17)


def project(X, R, t, focal: float, centre) -> np.ndarray:
    """Pixels ``(n, 2)`` of points ``X (n, 3)`` under the OpenCV camera (R, t, focal, centre)."""
    Xc = np.asarray(X, np.float64) @ np.asarray(R, np.float64).T + np.asarray(t, np.float64)
    z = np.maximum(Xc[:, 2], 1e-9)
    return np.column_stack([focal * Xc[:, 0] / z + centre[0], focal * Xc[:, 1] / z + centre[1]])


@dataclass(frozen=True)
class LandmarkFit:
    """The fitted head and camera. ``identity`` (the first ``n_identity`` weights),
    ``expression`` ({name: weight} of the weights above 0.01), ``R (3, 3)``, ``t (3,)`` (cm),
    ``focal`` (pixels), ``centre`` (the principal point), ``residual_px (68,)`` (distance of each
    projected model landmark to the given one), ``image_size``."""

    identity: np.ndarray
    expression: dict
    R: np.ndarray
    t: np.ndarray
    focal: float
    centre: tuple
    residual_px: np.ndarray
    image_size: tuple
    info: dict = field(default_factory=dict)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.focal, 0, self.centre[0]], [0, self.focal, self.centre[1]], [0, 0, 1.0]])

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.residual_px ** 2)))

    def head(self, model, parts="skin"):
        """The fitted head (an :class:`~geoface.synth.ict.ICTHead`, model coordinates, cm)."""
        return model.head(self.identity, self.expression, parts)

    def camera_dict(self) -> dict:
        """``{"K", "R", "t"}`` as the skin-texture commands read a camera file."""
        return {"K": self.K.tolist(), "R": np.asarray(self.R).tolist(), "t": np.asarray(self.t).tolist()}


def load_landmarks(path) -> tuple[np.ndarray, tuple | None]:
    """(68, 2) pixel landmarks and the image size written with them (or None); see the module."""
    p = Path(path)
    if not p.is_file():
        raise GeofaceError(f"{p}: no such landmarks file")
    size = None
    try:
        if p.suffix.lower() == ".json":
            d = json.loads(p.read_text(encoding="utf-8"))
            if isinstance(d, dict):
                size = tuple(int(x) for x in d["image_size"]) if d.get("image_size") else None
                d = d["landmarks"]
            L = np.asarray(d, np.float64)
        elif p.suffix.lower() == ".npy":
            L = np.load(p, allow_pickle=False).astype(np.float64)
        else:
            rows = [ln.split() for ln in p.read_text(encoding="utf-8").splitlines()]
            rows = [r for r in rows if len(r) == 2 and not r[0].startswith(("{", "}", "version", "n_points"))]
            L = np.asarray(rows, np.float64)
    except (OSError, ValueError, KeyError, TypeError, OverflowError, RecursionError) as e:
        raise GeofaceError(f"{p}: not a landmarks file ({type(e).__name__}: {str(e)[:100]}); see geoface.synth.ict_fit") from None
    if L.shape != (68, 2) or not np.isfinite(L).all():
        raise GeofaceError(f"{p}: need 68 finite (x, y) landmarks; got shape {L.shape}")
    if size is not None and (len(size) != 2 or not all(1 <= v <= 65536 for v in size)):
        raise GeofaceError(f"{p}: image_size must be [W, H], each in 1..65536; got {size}"[:200])
    if np.abs(L).max() > 1e6:
        raise GeofaceError(f"{p}: landmarks must be pixel positions (|x|, |y| up to 1e6); the largest is {np.abs(L).max():.3g}")
    spread = float(np.sqrt(((L - L.mean(0)) ** 2).sum(1).mean()))
    if spread < 1.0:
        raise GeofaceError(f"{p}: the 68 landmarks lie within {spread:.2g} px of one point; they are not a face")
    return L, size


def _rodrigues(r):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(r).as_matrix()


def fit_landmarks(model, landmarks, image_size, *, n_identity: int = 100, focal=None, iterations: int = 200,
                  jaw_weight: float = 0.5, identity_prior: float = 1.0, expression_prior: float = 0.5,
                  focal_prior: float = 0.5, holdout=None) -> LandmarkFit:
    """Fit ``model`` (an :class:`~geoface.synth.ict.ICTFaceModel`) to 68 pixel ``landmarks`` in an
    image of ``image_size`` (W, H). ``focal``: a known focal length in pixels (else fitted).
    ``holdout``: a (68,) bool mask of landmarks left out of the fit (their ``residual_px`` is
    then a held-out error; :func:`heldout_errors` does it fold by fold).
    ``identity_prior`` / ``expression_prior``: weights of the priors (in units of one pixel of
    residual per standard deviation / per unit weight)."""
    import cv2
    from scipy.optimize import least_squares

    L = np.asarray(landmarks, np.float64)
    if L.shape != (68, 2) or not np.isfinite(L).all():
        raise GeofaceError(f"landmarks must be 68 finite (x, y) pixels; got shape {L.shape}")
    W, H = (int(x) for x in image_size)
    if W < 8 or H < 8:
        raise GeofaceError(f"image_size must be (W, H) of at least 8 pixels; got {image_size}")
    k = int(n_identity)
    if not 0 <= k <= model.n_identities:
        raise GeofaceError(f"n_identity must be in 0..{model.n_identities}; got {n_identity}")
    v = model.view("skin")
    lm = v.landmarks
    mean = v.neutral[lm]                                    # (68, 3)
    Bi = v.identity_modes[:k, lm].astype(np.float64)       # (k, 68, 3)
    Be = v.expression_modes[:, lm].astype(np.float64)      # (E, 68, 3)
    E = len(Be)
    c = np.array([W / 2.0, H / 2.0])
    w = np.ones(68)
    w[JAW] = jaw_weight
    keep = np.ones(68, bool)
    if holdout is not None:
        keep = ~np.asarray(holdout, bool).reshape(68)
        if keep.sum() < 12:
            raise GeofaceError(f"holdout leaves {int(keep.sum())} landmarks to fit; need at least 12")
        w[~keep] = 0.0
    f0 = float(focal) if focal is not None else 1.2 * max(W, H)
    K0 = np.array([[f0, 0, c[0]], [0, f0, c[1]], [0, 0, 1.0]])
    ok, rvec, tvec = cv2.solvePnP(mean[keep], L[keep], K0, None, flags=cv2.SOLVEPNP_EPNP)
    if not ok:
        raise GeofaceError("the landmarks do not fit a face (PnP found no pose); check their order (Multi-PIE 68)")
    ok, rvec, tvec = cv2.solvePnP(mean[keep], L[keep], K0, None, rvec, tvec, useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if tvec[2, 0] <= 0:
        raise GeofaceError("the landmarks put the face behind the camera; check their order (Multi-PIE 68)")
    fit_f = focal is None

    def unpack(x):
        r, t = x[:3], x[3:6]
        f = float(np.exp(x[6])) if fit_f else f0
        a = x[7:7 + k]
        b = x[7 + k:]
        return r, t, f, a, b

    def shape(a, b):
        return mean + np.tensordot(a, Bi, axes=1) + np.tensordot(b, Be, axes=1)

    def residuals(x):
        r, t, f, a, b = unpack(x)
        P = project(shape(a, b), _rodrigues(r), t, f, c)
        return np.concatenate([((P - L) * w[:, None]).ravel(), identity_prior * a, expression_prior * b,
                               [focal_prior * (np.log(f) - np.log(f0))] if fit_f else []])

    n_prior = k + E + (1 if fit_f else 0)

    def jacobian(x):
        """Analytic in t, the identity and the expression weights (the shape is linear in them);
        central differences in the rotation and the focal length (4 columns)."""
        r, t, f, a, b = unpack(x)
        R = _rodrigues(r)
        S = shape(a, b)
        X = S @ R.T + t
        z = X[:, 2]
        # d pixel / d X: (68, 2, 3)
        D = np.zeros((68, 2, 3))
        D[:, 0, 0] = D[:, 1, 1] = f / z
        D[:, 0, 2] = -f * X[:, 0] / z ** 2
        D[:, 1, 2] = -f * X[:, 1] / z ** 2
        D *= w[:, None, None]
        J = np.zeros((136 + n_prior, len(x)))
        J[:136, 3:6] = D.reshape(136, 3)
        DR = np.einsum("nij,jk->nik", D, R)  # d pixel / d S
        if k:
            J[:136, 7:7 + k] = np.einsum("nij,mnj->nim", DR, Bi).reshape(136, k)
        J[:136, 7 + k:7 + k + E] = np.einsum("nij,mnj->nim", DR, Be).reshape(136, E)
        J[136 + np.arange(k), 7 + np.arange(k)] = identity_prior
        J[136 + k + np.arange(E), 7 + k + np.arange(E)] = expression_prior
        cols = [0, 1, 2] + ([6] if fit_f else [])
        for j in cols:
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            J[:, j] = (residuals(xp) - residuals(xm)) / (2 * h)
        return J

    x0 = np.concatenate([rvec.ravel(), tvec.ravel(), [np.log(f0)], np.zeros(k), np.zeros(E)])
    lo = np.concatenate([np.full(6, -np.inf), [np.log(0.2 * max(W, H))], np.full(k, -5.0), np.zeros(E)])
    hi = np.concatenate([np.full(6, np.inf), [np.log(20.0 * max(W, H))], np.full(k, 5.0), np.ones(E)])
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    res = least_squares(residuals, x0, jac=jacobian, bounds=(lo, hi), loss="huber", f_scale=1.0,
                        max_nfev=int(iterations), x_scale="jac")
    r, t, f, a, b = unpack(res.x)
    R = _rodrigues(r)
    P = project(shape(a, b), R, t, f, c)
    expr = {model.expression_names[j]: float(b[j]) for j in range(E) if b[j] > 0.01}
    return LandmarkFit(identity=a.copy(), expression=expr, R=R, t=np.asarray(t, np.float64), focal=f,
                       centre=(float(c[0]), float(c[1])), residual_px=np.linalg.norm(P - L, axis=1),
                       image_size=(W, H), info={"evaluations": int(res.nfev), "status": int(res.status),
                                                "cost": float(res.cost)})


def heldout_errors(model, landmarks, image_size, *, folds: int = 4, **kw) -> np.ndarray:
    """Each of the 68 ``landmarks``' distance (pixels) to the head fitted without it: the
    landmarks are split into ``folds`` interleaved folds (every ``folds``-th point, so each fold
    has points of every part of the face), and each fold is predicted by a fit to the others
    (:func:`fit_landmarks` with ``holdout``; ``kw`` passed on). A landmark tracker's points that
    the fitted head predicts from the rest agree with the face's shape, not only with themselves."""
    if not 2 <= int(folds) <= 17:
        raise GeofaceError(f"folds must be in 2..17; got {folds}")
    out = np.zeros(68)
    for k in range(int(folds)):
        hold = np.arange(68) % int(folds) == k
        out[hold] = fit_landmarks(model, landmarks, image_size, holdout=hold, **kw).residual_px[hold]
    return out
