"""Rigid head poses from 2D landmarks (perspective-n-point with a robust loss).

A video folder's landmarks (``landmarks.json``, any tracker's, see :mod:`hfm_data`) and its
canonical head (``head.ply``, in the pose of frame 0) give each frame's rigid head pose:

1. :func:`landmarks_on_mesh` puts frame 0's landmarks on the head: the ray through each
   landmark pixel meets the triangle the camera sees there (exact ray–plane intersection, so
   sub-pixel landmarks land sub-pixel on the surface); points the head does not cover (a jaw
   contour on the silhouette) are dropped;
   the jaw's outline, though, is where the face turns away from the camera: its ray meets the
   cheek in front of the true point (7–14 mm off on the ICT-FaceKit captures), so with the iBUG
   68 the outline points are instead **triangulated** (:func:`triangulate`) from all frames, seen
   through the poses that the points placed well (nose, eye corners) give (2 mm off there);
2. :func:`solve_poses` finds per frame the rotation and translation ``X' = R (X − pivot) +
   pivot + t`` that projects those 3D points onto the frame's landmarks, by Gauss–Newton with
   a soft-L1 and then a Cauchy loss (1 px scale) from the previous frame's pose: landmarks that
   expressions move (a smiling mouth corner, an open jaw) are down-weighted as outliers.  With the iBUG 68 only
   the points that move little with expressions are used (:data:`IBUG68_RIGID`).
"""
from __future__ import annotations

import numpy as np

from geoface.errors import AvatarError
from geoface.rotations import rodrigues, rodrigues_axes, rotation_vector  # noqa: F401  (re-exported)

__all__ = ["landmarks_on_mesh", "solve_poses", "triangulate", "poses_from_landmarks", "canonical_landmarks", "rodrigues",
           "rotation_vector", "repivot", "ray_offsets", "calibrate_lower_poses", "apply_lower_calibration", "calibration_scores", "expression_reach",
           "rigidity_weights",
           "landmark_expressions", "LOWER_RIGID_NAMES", "LOWER_STABLE_NAMES", "STABLE_NAMES"]

#: iBUG names below a headset that move little with expressions (nose base, the jaw line's ends)
LOWER_RIGID_NAMES = ("nose_tip", "nose_base_0", "nose_base_1", "nose_base_2", "nose_base_3", "nose_base_4",
                     "jaw_00", "jaw_01", "jaw_02", "jaw_14", "jaw_15", "jaw_16")
#: those of them that stay put best (the nose tip, the middle three points of the nose base, the
#: jaw line's two outermost points each side): no nose wings, which a sneer or a smile lifts, and
#: no third jaw points, which the mouth moves
LOWER_STABLE_NAMES = ("nose_tip", "nose_base_1", "nose_base_2", "nose_base_3", "jaw_00", "jaw_01", "jaw_15", "jaw_16")
#: iBUG names of the rigid landmarks that stay put best through expressions: the jaw line's two
#: outermost points each side, the nose ridge below its top, the nose tip and the middle of the nose
#: base, the eye corners (no nose wings, which a sneer or a smile lifts; no top of the nose ridge,
#: which a frown pulls; no third jaw points, which the mouth moves)
STABLE_NAMES = ("jaw_00", "jaw_01", "jaw_15", "jaw_16", "nose_bridge_1", "nose_bridge_2", "nose_tip", "nose_base_2",
                "eye_right_0", "eye_right_3", "eye_left_0", "eye_left_3")


def landmarks_on_mesh(V, F, camera, points2d) -> tuple[np.ndarray, np.ndarray]:
    """3D points [K, 3] where the camera rays through ``points2d`` [K, 2] (pixels) meet the mesh,
    and a bool [K]: whether the ray met it (NaN rows where not)."""
    from geoface.nn.mesh_render import rasterize_mesh

    V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
    pts = np.asarray(points2d, np.float64)
    face, _, _ = rasterize_mesh(V, F, camera)
    H, W = face.shape
    out = np.full((len(pts), 3), np.nan)
    ok = np.zeros(len(pts), bool)
    Rc, tc = np.asarray(camera.R, np.float64), np.asarray(camera.t, np.float64)
    origin = -Rc.T @ tc
    for i, (x, y) in enumerate(pts):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        c, r = int(np.floor(x)), int(np.floor(y))
        if not (0 <= r < H and 0 <= c < W) or face[r, c] < 0:
            continue
        d = Rc.T @ np.array([(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0])
        a, b, cc = V[F[face[r, c]]]
        n = np.cross(b - a, cc - a)
        den = float(n @ d)
        if abs(den) < 1e-15:
            continue
        out[i] = origin + d * float(n @ (a - origin)) / den
        ok[i] = True
    return out, ok


def project_points(camera, X):
    Xc = X @ np.asarray(camera.R, np.float64).T + np.asarray(camera.t, np.float64)
    return np.stack([camera.fx * Xc[:, 0] / Xc[:, 2] + camera.cx, camera.fy * Xc[:, 1] / Xc[:, 2] + camera.cy], 1)


def _pose_jacobian(camera, Q, piv, x, wk) -> np.ndarray:
    """(2K, 6): the derivative of :func:`solve_poses`'s residuals (the projections of
    ``R(x[:3]) Q + piv + x[3:]``, times ``wk``, raveled point by point) by ``x``."""
    Y = Q @ rodrigues(x[:3]).T
    Cr = np.asarray(camera.R, np.float64)
    Xc = (Y + piv + x[3:]) @ Cr.T + np.asarray(camera.t, np.float64)
    iz = 1.0 / Xc[:, 2]
    zero = np.zeros_like(iz)
    # d(u, v)/dXc per point: (K, 2, 3)
    P = np.stack([np.stack([camera.fx * iz, zero, -camera.fx * Xc[:, 0] * iz * iz], 1),
                  np.stack([zero, camera.fy * iz, -camera.fy * Xc[:, 1] * iz * iz], 1)], 1)
    dY = np.cross(rodrigues_axes(x[:3])[None, :, :], Y[:, None, :])  # (K, i, 3): ∂Y/∂x_i
    J = np.empty((len(Q), 2, 6))
    J[:, :, :3] = np.einsum("npj,jk,nik->npi", P, Cr, dY)
    J[:, :, 3:] = P @ Cr
    return (J * wk[:, :, None]).reshape(-1, 6)


def solve_poses(camera, points3d, points2d, pivot, *, init=None, scale_px: float = 1.0, weights=None) -> dict:
    """Per-frame rigid pose of ``points3d`` [K, 3] (canonical) seen at ``points2d`` [T, K, 2].

    Returns ``{"R": [T, 3, 3], "t": [T, 3], "pivot": [3], "rms_px": [T], "inliers": [T]}``
    (rms over the points within 3 × ``scale_px`` of their landmark).  Each frame starts from the
    previous frame's solution (``init`` = (R, t) for frame 0, default the identity); NaN
    landmarks are skipped.  ``weights`` [K] (> 0): each point's weight in the least squares
    (e.g. :func:`rigidity_weights`), default equal.  Raises AvatarError when a frame has fewer
    than 4 points."""
    from scipy.optimize import least_squares

    P = np.asarray(points3d, np.float64)
    obs = np.asarray(points2d, np.float64)
    w = np.ones(len(P)) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (len(P),) or not (np.isfinite(w).all() and (w > 0).all()):
        raise AvatarError(f"solve_poses: weights must be {len(P)} positive numbers")
    sw = np.sqrt(w)
    piv = np.asarray(pivot, np.float64)
    T = len(obs)
    R0, t0 = (np.eye(3), np.zeros(3)) if init is None else (np.asarray(init[0], np.float64), np.asarray(init[1], np.float64))
    x = np.r_[rotation_vector(R0), t0]
    Rs, ts, rms, inl = np.zeros((T, 3, 3)), np.zeros((T, 3)), np.zeros(T), np.zeros(T, int)
    for f in range(T):
        ok = np.isfinite(obs[f]).all(1) & np.isfinite(P).all(1)
        if ok.sum() < 4:
            raise AvatarError(f"frame {f}: only {int(ok.sum())} usable landmarks for the head pose (need 4)")
        Q, q, wk = P[ok] - piv, obs[f][ok], sw[ok, None]

        def resid(x):
            X = Q @ rodrigues(x[:3]).T + piv + x[3:]
            return ((project_points(camera, X) - q) * wk).ravel()

        def jac(x):
            return _pose_jacobian(camera, Q, piv, x, wk)

        # soft-L1 first (close to convex), then Cauchy from there (ignores moved points more)
        sol = least_squares(resid, x, jac=jac, loss="soft_l1", f_scale=2 * scale_px, method="trf", x_scale="jac", max_nfev=200)
        sol = least_squares(resid, sol.x, jac=jac, loss="cauchy", f_scale=scale_px, method="trf", x_scale="jac", max_nfev=200)
        x = sol.x
        e = np.linalg.norm(sol.fun.reshape(-1, 2) / wk, axis=1)
        good = e < 3 * scale_px
        Rs[f], ts[f] = rodrigues(x[:3]), x[3:]
        rms[f] = float(np.sqrt(np.mean(e[good] ** 2))) if good.any() else float("nan")
        inl[f] = int(good.sum())
    return {"R": Rs, "t": ts, "pivot": piv, "rms_px": rms, "inliers": inl}


def triangulate(camera, poses: dict, points2d, init, *, scale_px: float = 1.0) -> np.ndarray:
    """Canonical 3D points [K, 3] that the poses (``solve_poses``'s dict: R, t, pivot) project
    onto ``points2d`` [T, K, 2] (NaN skipped), each by a robust (Cauchy, ``scale_px``) least
    squares over the frames from ``init`` [K, 3]; a point seen in fewer than 2 frames keeps its
    ``init``."""
    from scipy.optimize import least_squares

    R, t, piv = (np.asarray(poses[k], np.float64) for k in ("R", "t", "pivot"))
    obs = np.asarray(points2d, np.float64)
    out = np.array(init, np.float64, copy=True)
    for k in range(obs.shape[1]):
        ok = np.isfinite(obs[:, k]).all(1)
        if ok.sum() < 2 or not np.isfinite(out[k]).all():
            continue
        Rk, tk, q = R[ok], t[ok], obs[ok, k]

        def resid(X):
            Xw = np.einsum("fij,j->fi", Rk, X - piv) + piv + tk
            return (project_points(camera, Xw) - q).ravel()

        out[k] = least_squares(resid, out[k], loss="cauchy", f_scale=scale_px, method="trf", x_scale="jac",
                               max_nfev=200).x
    return out


def canonical_landmarks(video, mesh_V, mesh_F, pose0=None) -> tuple[list, np.ndarray]:
    """(names, points [K, 3]) of ``video``'s frame-0 landmarks placed on the canonical head
    (frame 0 seen through its pose ``pose0`` = (R, t, pivot) when given, else the head as it is);
    landmarks off the head are left out."""
    V = np.asarray(mesh_V, np.float64)
    if pose0 is not None:
        R, t, p = (np.asarray(a, np.float64) for a in pose0)
        V = (V - p) @ R.T + p + t
    P, ok = landmarks_on_mesh(V, mesh_F, video.camera, video.landmarks[0])
    if pose0 is not None:
        P = (P - p - t) @ R + p  # back to the canonical pose
    return [n for n, k in zip(video.names, ok) if k], P[ok]


def poses_from_landmarks(video, mesh_V, mesh_F, *, indices=None, fit_names=None) -> dict:
    """Head poses of every frame of ``video`` (an :class:`HMDVideo`) from its landmarks and its
    canonical head (``mesh_V``, ``mesh_F``; frame 0's pose).  ``indices``: which landmarks place
    the head (default: the iBUG rigid ones when the names are the iBUG 68, else all); the poses
    are fitted to those, or to the landmarks named ``fit_names`` when given (e.g.
    :data:`LOWER_RIGID_NAMES`, those a headset leaves visible).  The pivot is the mean of the
    placing landmarks either way.  Returns :func:`solve_poses`'s dict plus ``points3d`` [K, 3] and
    ``names`` of the points fitted, and ``all_names`` / ``all_points3d``: every landmark that frame 0
    places on the head."""
    from geoface.avatar.capture import IBUG68_NAMES, IBUG68_RIGID

    names = list(video.names)
    if indices is None:
        indices = list(IBUG68_RIGID) if tuple(names) == tuple(IBUG68_NAMES) else list(range(len(names)))
    placed, P_all = canonical_landmarks(video, mesh_V, mesh_F)
    use = [names[i] for i in indices if names[i] in placed]
    if len(use) < 4:
        raise AvatarError(f"only {len(use)} of frame 0's landmarks fall on the head mesh: cannot fit head poses "
                         "(is head.ply in frame 0's pose, and camera.json right?)")
    pivot = P_all[[placed.index(n) for n in use]].mean(0)
    outline = [n for n in placed if n.startswith("jaw_")] if tuple(names) == tuple(IBUG68_NAMES) else []
    inner = [n for n in use if n not in outline]
    if outline and len(inner) >= 4 and len(video) >= 2:
        # the outline's rays graze the cheek: triangulate it through the poses of the inner points
        first = solve_poses(video.camera, P_all[[placed.index(n) for n in inner]],
                            video.landmarks[:, [names.index(n) for n in inner]], pivot)
        k = [placed.index(n) for n in outline]
        P_all = P_all.copy()
        P_all[k] = triangulate(video.camera, first, video.landmarks[:, [names.index(n) for n in outline]], P_all[k])
    if fit_names is not None:
        use = [n for n in names if n in fit_names and n in placed]
        if len(use) < 4:
            raise AvatarError(f"only {len(use)} of the landmarks to fit the head poses to fall on the head mesh (need 4)")
    P3 = P_all[[placed.index(n) for n in use]]
    out = solve_poses(video.camera, P3, video.landmarks[:, [names.index(n) for n in use]], pivot)
    out.update(points3d=P3, names=use, all_names=placed, all_points3d=P_all)
    return out


def ray_offsets(camera, R, t, pivot, points3d, points2d) -> np.ndarray:
    """[T, K, 3]: for each frame and point, the shortest move (in the canonical frame) that puts
    ``points3d`` [K, 3], seen in the frame's pose ``X' = R (X − pivot) + pivot + t``, on the camera
    ray of its landmark ``points2d`` [T, K, 2] — what the landmarks say the face did beside the
    rigid motion, to first order."""
    Rc, tc = np.asarray(camera.R, np.float64), np.asarray(camera.t, np.float64)
    C = -Rc.T @ tc
    P, obs, piv = (np.asarray(a, np.float64) for a in (points3d, points2d, pivot))
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    out = np.zeros(obs.shape[:2] + (3,))
    for f in range(len(obs)):
        X = (P - piv) @ R[f].T + piv + t[f]
        d = np.stack([(obs[f, :, 0] - camera.cx) / camera.fx, (obs[f, :, 1] - camera.cy) / camera.fy,
                      np.ones(len(P))], 1) @ Rc  # ray directions in the world
        s = ((X - C) * d).sum(1) / (d * d).sum(1)
        out[f] = (C + d * s[:, None] - X) @ R[f]
    return out


def rigidity_weights(camera, R, t, pivot, points3d, points2d, floor_m: float = 3e-4) -> np.ndarray:
    """[K] weights, mean 1, of landmarks by how little they move on the head: 1 / (v + ``floor_m``²)
    with v the variance over the frames of :func:`ray_offsets` (what the landmark did beside the
    rigid motion ``R``, ``t`` about ``pivot``).  On a person's registration video this says which
    of the "rigid" landmarks stay put through that person's expressions (the jaw line's ends and
    the nose tip, more than the nose wings), for fitting poses to them (:func:`solve_poses`)."""
    off = ray_offsets(camera, R, t, pivot, points3d, points2d)
    ok = np.isfinite(off).all(2)
    v = np.array([np.mean(np.sum((off[ok[:, k], k] - off[ok[:, k], k].mean(0)) ** 2, 1)) if ok[:, k].sum() > 1
                  else np.nan for k in range(off.shape[1])])
    w = 1.0 / (np.where(np.isfinite(v), v, np.nanmax(v, initial=0.0)) + floor_m**2)
    return w / w.mean()


def repivot(R, t, pivot, new_pivot) -> np.ndarray:
    """Translations [T, 3] that express the motions ``X' = R (X − pivot) + pivot + t`` (R [T, 3, 3],
    t [T, 3]) about ``new_pivot`` instead: the same rigid motions, another centre."""
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    p, q = np.asarray(pivot, np.float64), np.asarray(new_pivot, np.float64)
    return (p - R @ p + t) - (q - R @ q)


def _pose_delta(R0, t0, R1, t1) -> np.ndarray:
    """[T, 6]: pose 1 against pose 0 (same pivot): rotation vector of R0ᵀ R1, t1 − t0."""
    return np.array([np.r_[rotation_vector(R0[f].T @ R1[f]), t1[f] - t0[f]] for f in range(len(R0))])


def calibrate_lower_poses(camera, names, points3d, landmarks, frame_names, poses, *, fit_names=LOWER_RIGID_NAMES,
                          feature_names=(), components: int = 8, ridge: float = 0.01,
                          weighted: bool = False, expressions: dict | None = None, draws: int = 0,
                          seed: int = 0) -> dict | None:
    """How the head poses fitted to the landmarks below a headset (``fit_names``) miss the poses
    that define a model's frame, as a linear function of the lower face's shape, learned on the
    registration video where both are known.

    Expressions move the lower "rigid" landmarks (a sneer lifts the nose wings, a smile pulls
    them), and the pose fitted to them alone tilts with the expression (0.3–0.6° on some ICT
    people's usage videos), while the registration poses, fitted to all rigid landmarks with the
    eye corners and nose bridge, tilt in their own way — the frame the avatar learned.  Per
    registration frame: ``Y`` = the registration pose against the lower-landmark pose (rotation
    vector, translation; about the fitted points' mean); features = :func:`ray_offsets` of the
    landmarks ``feature_names`` (the lower face's, mouth included) against the lower-landmark
    pose; ``Y`` is regressed on the leading ``components`` principal components of the features by
    ridge regression (``ridge``: the penalty relative to the components' mean variance).
    ``weighted``: the lower-landmark poses weigh each fit point by how little it moved in these
    frames (:func:`rigidity_weights` against ``poses``; saved as ``fit_weights``, and the usage
    poses must be fitted with them).
    ``expressions`` (name → [J, 3], :func:`landmark_expressions`) with ``draws`` > 0: each
    registration frame is also seen ``draws`` times with 1–3 random expressions of that basis (weights
    uniform in [0, 1]) added to its landmarks, in its registration pose, so the regression also
    learns expressions the person did not make in registration (a usage video's broad smile); the
    weights of ``weighted`` are the registration frames' alone (the person's own).

    ``names`` / ``points3d``: the landmarks placed on the canonical head; ``landmarks``
    [T, K, 2] the video's, named ``frame_names``; ``poses`` = (R [T, 3, 3], t [T, 3], pivot).
    With at least four frames per component the dict also keeps how far the frames' features
    spread along each component (``score_sd``) and the largest distance of a frame from the mean
    face in those units (``score_reach``), which say when a usage video's expressions lie beyond
    the calibration's (:func:`expression_reach`).
    Returns a JSON-able dict for :func:`apply_lower_calibration`, or None when fewer than 4 fit
    points or fewer frames than components + 2 are there."""
    placed = {n: i for i, n in enumerate(names)}
    col = {n: i for i, n in enumerate(frame_names)}
    fit = [n for n in fit_names if n in placed and n in col]
    feat = [n for n in feature_names if n in placed and n in col]
    obs = np.asarray(landmarks, np.float64)
    ok = np.isfinite(obs[:, [col[n] for n in fit + feat]]).all((1, 2))
    k = int(min(components, 3 * len(feat)))
    if len(fit) < 4 or k < 1 or ok.sum() < k + 2:
        return None
    P = np.asarray(points3d, np.float64)
    Pf = P[[placed[n] for n in fit]]
    piv = Pf.mean(0)
    R, t, p = (np.asarray(a, np.float64) for a in poses)
    R, obs = R[ok], obs[ok]
    t = repivot(R, t[ok], p, piv)
    fit_obs = obs[:, [col[n] for n in fit]]
    w = rigidity_weights(camera, R, t, piv, Pf, fit_obs) if weighted else None
    both = fit + feat
    if expressions is not None and draws > 0 and all(n in expressions for n in both):
        obs, R, t = _with_expressions(camera, P[[placed[n] for n in both]], obs, [col[n] for n in both], R, t, piv,
                                      np.stack([np.asarray(expressions[n], np.float64) for n in both], 1), draws, seed)
        fit_obs = obs[:, [col[n] for n in fit]]
    low = solve_poses(camera, Pf, fit_obs, piv, weights=w)
    Y = _pose_delta(low["R"], low["t"], R, t)
    F = ray_offsets(camera, low["R"], low["t"], piv, P[[placed[n] for n in feat]],
                    obs[:, [col[n] for n in feat]]).reshape(len(Y), -1)
    mean, off = F.mean(0), Y.mean(0)
    _, S, Vt = np.linalg.svd(F - mean, full_matrices=False)
    Z = (F - mean) @ Vt[:k].T
    lam = ridge * float(np.mean(S[:k] ** 2))
    W = np.linalg.solve(Z.T @ Z + lam * np.eye(k), Z.T @ (Y - off))
    out = {"fit_names": fit, "names": feat, "pivot": piv.tolist(), "mean": mean.tolist(), "basis": Vt[:k].tolist(),
           "weights": W.tolist(), "offset": off.tolist(), **({"fit_weights": w.tolist()} if weighted else {})}
    if len(Z) >= 4 * k:  # fewer frames do not say how far the expressions spread
        sd = Z.std(0)
        sd = np.maximum(sd, 1e-9 * max(float(sd.max()), 1e-30))  # a component the frames never moved along
        out.update(score_sd=sd.tolist(), score_reach=float(np.sqrt(((Z / sd) ** 2).sum(1)).max()))
    return out


def _with_expressions(camera, P, obs, cols, R, t, piv, B, draws: int, seed: int):
    """The frames (landmarks ``obs`` [T, K, 2], poses R, t about ``piv``) followed by ``draws`` copies
    of each with 1–3 random rows of ``B`` [J, k, 3] (weights in [0, 1]) added, in the canonical
    frame, to where the landmarks ``cols`` (canonical points ``P`` [k, 3]) were, seen in the frame's pose."""
    rng = np.random.default_rng(seed)
    off = ray_offsets(camera, R, t, piv, P, obs[:, cols])
    T, J = len(obs), len(B)
    new = np.repeat(obs, draws, 0)
    for i in range(T * draws):
        f, w = i // draws, np.zeros(J)
        pick = rng.choice(J, size=int(rng.integers(1, min(3, J) + 1)), replace=False)
        w[pick] = rng.uniform(0.0, 1.0, len(pick))
        X = (P + off[f] + np.einsum("j,jkc->kc", w, B) - piv) @ R[f].T + piv + t[f]
        new[i, cols] = project_points(camera, X)
    return np.concatenate([obs, new]), np.concatenate([R, np.repeat(R, draws, 0)]), np.concatenate([t, np.repeat(t, draws, 0)])


def landmark_expressions(names, points3d, *, model=None) -> dict | None:
    """How the expressions of the ICT-FaceKit model (built from scans of real people; shipped with
    geoface) move the iBUG-68 landmarks ``names`` placed at ``points3d`` [K, 3] on a head: name →
    [J, 3] displacements (metres) of its J lower-face blendshapes (brows and lids left out), from the
    model's mean head, turned and scaled into the head's frame by the similarity that best maps the
    model's landmarks onto ``points3d``.  None when fewer than 6 names are iBUG-68 or the model is
    not found."""
    from geoface.mesh.align import similarity_transform
    from geoface.avatar.capture import IBUG68_NAMES
    from geoface.synth.ict import find_model, load_ict_model

    idx = [IBUG68_NAMES.index(n) if n in IBUG68_NAMES else -1 for n in names]
    ok = np.array(idx) >= 0
    if ok.sum() < 6 or (model is None and find_model(required=False) is None):
        return None
    model = model if model is not None else load_ict_model()
    base = model.shape(None)
    L = model.landmarks
    keep = [j for j, n in enumerate(model.expression_names) if not n.startswith(("eye", "brow"))]
    D = np.asarray(model.expression_modes, np.float64)[keep][:, L]  # [J, 68, 3], model units (shape is linear in them)
    scale, Q, _ = similarity_transform(base[L][np.array(idx)[ok]], np.asarray(points3d, np.float64)[ok])
    return {n: scale * D[:, i] @ Q.T for n, i in zip(names, idx) if i >= 0}


def calibration_scores(cal: dict, camera, points3d_of: dict, landmarks, frame_names, R, t, pivot) -> np.ndarray | None:
    """[T, k]: the lower face's expression features that :func:`calibrate_lower_poses`' ``cal``
    reads, per frame (its principal-component scores, zero at the registration's mean face), for
    poses (R [T, 3, 3], t [T, 3], about ``pivot``) fitted to the video's lower landmarks;
    ``points3d_of``: name → canonical point.  None when the video lacks one of the landmarks."""
    col = {n: i for i, n in enumerate(frame_names)}
    if any(n not in col or n not in points3d_of for n in cal["names"]):
        return None
    obs = np.asarray(landmarks, np.float64)[:, [col[n] for n in cal["names"]]]
    if not np.isfinite(obs).all():
        return None
    R, t, p = np.asarray(R, np.float64), np.asarray(t, np.float64), np.asarray(pivot, np.float64)
    piv = np.asarray(cal["pivot"], np.float64)
    F = ray_offsets(camera, R, repivot(R, t, p, piv), piv, np.array([points3d_of[n] for n in cal["names"]]),
                    obs).reshape(len(R), -1)
    return (F - np.asarray(cal["mean"])) @ np.asarray(cal["basis"]).T


def expression_reach(cal: dict, Z) -> np.ndarray | None:
    """[T]: how far each frame's lower-face expression (``Z``, :func:`calibration_scores`) lies from
    the registration's mean face, in units of the farthest frame ``cal`` learned from (Mahalanobis
    distance over the components' spreads, divided by the registration's largest).  Above 1 the
    expression is beyond any the calibration saw, and its correction an extrapolation.  None when
    ``Z`` is None or ``cal`` was made before it kept the spreads (``score_sd``, ``score_reach``)."""
    if Z is None or "score_sd" not in cal or "score_reach" not in cal:
        return None
    d = np.sqrt(((np.asarray(Z, np.float64) / np.asarray(cal["score_sd"], np.float64)) ** 2).sum(1))
    return d / float(cal["score_reach"])


def apply_lower_calibration(cal: dict, camera, points3d_of: dict, landmarks, frame_names, R, t, pivot):
    """Correct poses (R [T, 3, 3], t [T, 3], about ``pivot``) fitted to a video's lower landmarks
    by :func:`calibrate_lower_poses`' ``cal``; ``points3d_of``: name → canonical point.  Returns
    (R, t) about the same pivot, or None when the video lacks one of the landmarks ``cal`` reads."""
    Z = calibration_scores(cal, camera, points3d_of, landmarks, frame_names, R, t, pivot)
    if Z is None:
        return None
    R, t, p = np.asarray(R, np.float64), np.asarray(t, np.float64), np.asarray(pivot, np.float64)
    piv = np.asarray(cal["pivot"], np.float64)
    tq = repivot(R, t, p, piv)
    D = Z @ np.asarray(cal["weights"]) + np.asarray(cal["offset"])
    R2 = np.array([R[f] @ rodrigues(D[f, :3]) for f in range(len(R))])
    t2 = tq + D[:, 3:]
    return R2, repivot(R2, t2, piv, p)
