"""Head poses corrected by the headset's silhouette.

A head-mounted display is rigid with the head and seen in every usage frame, so where its
silhouette (``hmd_masks/``) lies says where the upper face is — the part the avatar must draw and
the lower-face landmarks place worst: an expression the registration video never showed (a broad
smile pulls the nose wings and the jaw line) shifts the pose fitted to the landmarks below the
headset, and the calibration learned in registration (:func:`~geoface.avatar.head_pose.calibrate_lower_poses`)
cannot know it.

1. :func:`headset_centroids`: each mask's centroid (sub-pixel: the mean of many pixels); masks
   that touch the image border (a silhouette cut off) or have few pixels are left out;
2. :func:`fit_headset`: a model of where the centroid falls in a pose — a point ``c`` of the head
   projected, plus a linear map ``A`` of the direction the headset is seen from (in the head's
   frame): a turned head shows a side of the headset and nearer parts of it cover more of the
   image, which moves the centroid off any one point, smoothly to first order.  The poses are
   wrong in the frames with unseen expressions, so ``c`` and ``A`` are fitted jointly with a
   linear map ``B`` from the lower face's expression features ``z`` (the calibration's scores,
   zero at the registration's mean face) to the centroid's misfit:
   ``π(R (c − pivot) + pivot + t) + A v − m ≈ B z``.  Where ``z`` is zero — expressions like the
   registration's — the poses are right on average, which pins ``c``; ``B`` takes up what the
   expressions do to the poses (ridge-penalised).  A weak prior holds ``c`` near a given point
   (the depth along the rays is barely seen under small head motion).  What the model cannot
   follow: a face of the headset coming into view or leaving it (a kink in the centroid's
   path), and a binary mask's edge quantisation (about 0.1 px of centroid noise at 128 px);
3. :func:`refine_with_headset`: per frame, the pose nearest the landmark pose (in the
   landmarks' own information metric ``JᵀJ``) whose predicted centroid is moved by ``−B z``:
   the two directions the centroid sees are corrected, the other four stay the landmarks'.
   :func:`headset_poses` does 2–3 from the centroids of 1.

On the ICT-FaceKit validation people whose usage video smiles beyond their registration video it
halves the upper face's pose error against the truth, yet the restored frames lose (the avatar
learned its face under the registration poses, whose own error moves with the expression):
``HFMConfig.headset_pose`` is off by default (``docs/hmd.md``).
"""
from __future__ import annotations

import numpy as np

from geoface.errors import AvatarError
from geoface.avatar.head_pose import project_points, rodrigues, rotation_vector

__all__ = ["headset_centroids", "headset_components", "fit_headset", "refine_with_headset", "headset_poses"]


def headset_centroids(masks, min_pixels: int = 20) -> np.ndarray:
    """[T, 2] centroid (x, y pixels) of each headset mask [T, H, W]; NaN where the mask has fewer
    than ``min_pixels`` pixels or touches the image border (cut off: its centroid is not the
    headset's)."""
    M = np.asarray(masks, bool)
    if M.ndim != 3:
        raise AvatarError(f"headset masks must be [T, H, W]; got shape {M.shape}")
    out = np.full((len(M), 2), np.nan)
    for f, m in enumerate(M):
        if m.sum() < min_pixels or m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any():
            continue
        ys, xs = np.nonzero(m)
        out[f] = xs.mean() + 0.5, ys.mean() + 0.5  # pixel centres
    return out


def headset_components(frames: int, components: int) -> int:
    """How many expression components (of ``components``) :func:`headset_poses` fits with
    ``frames`` whole masks: its unknowns (anchor 3, view map 4, two per component) at most a
    quarter of the centroids' 2 × frames numbers; 0 = too few frames for the model."""
    return int(max(0, min(components, (frames // 2 - 7) // 2)))


def _centre(camera) -> np.ndarray:
    return -np.asarray(camera.R, np.float64).T @ np.asarray(camera.t, np.float64)


def _predict(camera, R, t, pivot, c, A=None) -> np.ndarray:
    """[T, 2]: where the model (:func:`fit_headset`: point ``c``, view map ``A`` [2, 2]) puts the
    silhouette's centroid in each pose (R [T, 3, 3], t [T, 3] about ``pivot``)."""
    X = np.einsum("fij,j->fi", R, np.asarray(c, np.float64) - pivot) + pivot + t
    uv = project_points(camera, X)
    if A is not None:
        d = _centre(camera) - X
        d = np.einsum("fji,fj->fi", R, d / np.linalg.norm(d, axis=1, keepdims=True))  # in the head's frame
        uv = uv + d[:, :2] @ np.asarray(A).T
    return uv


def fit_headset(camera, R, t, pivot, centroids, init, *, scores=None, ridge: float = 0.1, view: bool = True,
                prior_px_per_m: float = 10.0) -> dict:
    """The headset model of the module doc from poses (R [T, 3, 3], t [T, 3] about ``pivot``), the
    masks' ``centroids`` [T, 2] (NaN rows skipped) and expression ``scores`` [T, k] (zero at the
    registration's mean face; None: no expression map).  ``init`` [3]: a head point near the
    headset; ``view``: fit the view map ``A``; ``ridge``: B's penalty, per score standard deviation,
    against one pixel of misfit in every frame; ``prior_px_per_m``: the pull of ``init`` (pixels
    per metre).  Returns ``{"anchor": c [3], "view": A [2, 2] or None, "expression": B [2, k] or
    None, "rms_px": the misfit}``.  Raises AvatarError with fewer than 6 usable centroids."""
    from scipy.optimize import least_squares

    R, t, piv = (np.asarray(a, np.float64) for a in (R, t, pivot))
    m = np.asarray(centroids, np.float64)
    ok = np.isfinite(m).all(1)
    if ok.sum() < 6:
        raise AvatarError(f"the headset masks give {int(ok.sum())} usable centroids (need 6)")
    R, t, m = R[ok], t[ok], m[ok]
    c0 = np.asarray(init, np.float64)
    Z = None if scores is None else np.asarray(scores, np.float64)[ok]
    k = 0 if Z is None else Z.shape[1]
    sd = Z.std(0) + 1e-12 if k else None
    w_ridge = np.sqrt(ridge * len(m))
    nv = 4 if view else 0

    def split(x):
        return x[:3], (x[3:3 + nv].reshape(2, 2) if view else None), (x[3 + nv:].reshape(2, k) if k else None)

    def resid(x):
        c, A, B = split(x)
        r = _predict(camera, R, t, piv, c, A) - m
        parts = [prior_px_per_m * (c - c0)]
        if k:
            r = r - Z @ B.T
            parts.append(w_ridge * (B * sd).ravel())
        return np.concatenate([r.ravel(), *parts])

    sol = least_squares(resid, np.r_[c0, np.zeros(nv + 2 * k)], method="trf", x_scale="jac")
    c, A, B = split(sol.x)
    rms = float(np.sqrt(np.mean(sol.fun[:2 * len(m)] ** 2) * 2))
    return {"anchor": c, "view": A, "expression": B, "rms_px": rms}


def refine_with_headset(camera, R, t, pivot, points3d, headset: dict, targets, *, weights=None,
                        sigma_landmarks_px: float = 1.0, sigma_headset_px: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Poses (R, t about ``pivot``) moved, frame by frame, as little as the landmarks allow (their
    information at the pose: the landmark points ``points3d`` [K, 3] with ``weights`` [K], each
    seen to ``sigma_landmarks_px``) to put the silhouette centroid that ``headset``
    (:func:`fit_headset`) predicts on the frame's ``targets`` [T, 2] pixels (to
    ``sigma_headset_px``).  Frames with a NaN target keep their pose."""
    from scipy.optimize import least_squares

    R, t, piv = (np.asarray(a, np.float64) for a in (R, t, pivot))
    Q = np.asarray(points3d, np.float64) - piv
    sw = np.sqrt(np.ones(len(Q)) if weights is None else np.asarray(weights, np.float64))[:, None]
    c, A = headset["anchor"], headset["view"]
    m = np.asarray(targets, np.float64)
    R2, t2 = R.copy(), t.copy()
    eps = 1e-6
    for f in range(len(R)):
        if not np.isfinite(m[f]).all():
            continue
        x0 = np.r_[rotation_vector(R[f]), t[f]]

        def lm(x):
            return ((project_points(camera, Q @ rodrigues(x[:3]).T + piv + x[3:])) * sw / sigma_landmarks_px).ravel()

        J = np.stack([(lm(x0 + d) - lm(x0 - d)) / (2 * eps) for d in np.eye(6) * eps], 1)
        L = np.linalg.cholesky(J.T @ J + 1e-9 * np.eye(6)).T

        def resid(x):
            pc = _predict(camera, rodrigues(x[:3])[None], x[None, 3:], piv, c, A)[0]
            return np.r_[L @ (x - x0), (pc - m[f]) / sigma_headset_px]

        x = least_squares(resid, x0, method="lm").x
        R2[f], t2[f] = rodrigues(x[:3]), x[3:]
    return R2, t2


def headset_poses(camera, R, t, pivot, points3d, centroids, init, scores, *, weights=None,
                  ridge: float = 0.1) -> tuple[np.ndarray, np.ndarray, dict]:
    """Poses (R [T, 3, 3], t [T, 3] about ``pivot``, fitted to the landmarks ``points3d`` [K, 3]
    with ``weights`` and calibrated) corrected by the headset masks' ``centroids`` [T, 2]
    (:func:`headset_centroids`): the headset
    model fitted with the expression ``scores`` [T, k] (:func:`fit_headset`; ``init``: a head
    point near the headset), then each frame's pose moved so that the predicted centroid moves by
    what the expressions did to it (``−B z``; frames whose mask is cut off are corrected too).  The
    leading :func:`headset_components` scores are used; AvatarError when the masks are too few.
    Returns (R, t, info: the model's misfit, usable frames, mean and largest correction in
    pixels)."""
    R, t, piv = (np.asarray(a, np.float64) for a in (R, t, pivot))
    cen = np.asarray(centroids, np.float64)
    whole = int(np.isfinite(cen).all(1).sum())
    k = headset_components(whole, np.shape(scores)[1])
    if k < 1:
        raise AvatarError(f"{whole} whole headset masks are too few for the headset's model (need 18)")
    Z = np.asarray(scores, np.float64)[:, :k]
    h = fit_headset(camera, R, t, piv, cen, init, scores=Z, ridge=ridge)
    shift = -Z @ h["expression"].T
    targets = _predict(camera, R, t, piv, h["anchor"], h["view"]) + shift
    R2, t2 = refine_with_headset(camera, R, t, piv, points3d, h, targets, weights=weights)
    n = np.linalg.norm(shift, axis=1)
    info = {"headset_rms_px": round(h["rms_px"], 4), "headset_frames": whole,
            "headset_shift_px_mean": round(float(n.mean()), 4), "headset_shift_px_max": round(float(n.max()), 4)}
    return R2, t2, info
