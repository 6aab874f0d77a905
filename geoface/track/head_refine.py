"""The ICT head track refined against the pixels (:func:`refine_photometric`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoface.errors import GeofaceError
from geoface.track.head_solver import expmap as _expmap, skew as _skew
from geoface.track.head_track import (CM_TO_M, CHEEKS, HeadTrack, point_bases, model_view, mediapipe_on_ict,
                                      view_offsets)

__all__ = ["refine_photometric", "Refinement"]


#: the colour noise the photometric term expects (RGB in [0, 1]): its residuals' unit
_COLOUR_NOISE = 0.05


@dataclass(frozen=True)
class Refinement:
    """What :func:`refine_photometric` measured: per frame the photometric error (mean absolute
    RGB difference over the visible face, in [0, 1] units) of the track before and after, and the
    seconds it took."""

    before: np.ndarray
    after: np.ndarray
    seconds: float


def _face_samples():
    """The ICT head's vertices the photometric term looks at: the face (the model's narrow face,
    where the texture is: brows, lids, nostrils, lips), and the skin's triangles for visibility."""
    v = model_view()
    return np.flatnonzero(v.labels == 0), v.F[np.isin(v.labels[v.F], (0, 1, 2)).all(1)]


def _bilinear(img, uv):
    """``img (H, W, C)`` at pixel positions ``uv (n, 2)`` (x, y; pixel centres at +0.5), bilinear."""
    H, W = img.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0, W - 1.001)
    y = np.clip(uv[:, 1] - 0.5, 0, H - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def _pixel_jacobian(f, RX, Xc, B, R):
    """How points move in the image, ``(n, 2, 59)``, under a frame's 59 unknowns (a turn, a shift,
    the 53 expression weights): points ``Xc (n, 3)`` in the camera, ``RX`` the same before the
    shift, ``B (53, n, 3)`` their expression modes in the head's frame, ``R`` the head's turn, ``f``
    the focal length. The projection's 2×3 derivative is applied written out (its zeros skipped:
    batched 2×3 products are slow)."""
    z = Xc[:, 2]
    dX = np.empty((len(z), 3, 59))
    dX[..., 0:3] = -_skew(RX)
    dX[..., 3:6] = np.eye(3)
    dX[..., 6:] = (B @ R.T).transpose(1, 2, 0)
    a, bx, by = f / z, -f * Xc[:, 0] / z ** 2, -f * Xc[:, 1] / z ** 2
    return np.stack([a[:, None] * dX[:, 0] + bx[:, None] * dX[:, 2], a[:, None] * dX[:, 1] + by[:, None] * dX[:, 2]], 1)


def refine_photometric(track: HeadTrack, frames, masks, points=None, *, passes: int = 3, iterations: int = 4,
                       blur=(2.0, 1.0), w_landmarks: float = 0.05, w_smooth: float = 0.5,
                       quiet: bool | None = None) -> tuple[HeadTrack, Refinement]:
    """The track refined against the pixels: each frame's pose and expressions moved so that the
    head's colours (taken from the frames themselves, :func:`head_texture`) match the frame where
    the head is seen — a dense, direct alignment of the face's texture (as analysis-by-synthesis
    trackers do), by Gauss–Newton on the visible face vertices (a z-buffer decides which), coarse
    to fine over ``blur`` (Gaussian σ in pixels), with each frame's colour gain and offset per
    channel, the landmarks (``points``, the face mesh's 468 as fitted, weight ``w_landmarks``)
    and the neighbours' poses and expressions (``w_smooth``) keeping it in place. The colours
    are taken again after each of ``passes`` passes. ``frames (T, H, W, 3)`` float in [0, 1],
    ``masks (T, H, W)`` the person. Returns the refined track and the errors before and after."""
    import time

    from scipy.ndimage import gaussian_filter
    from scipy.spatial.transform import Rotation

    from geoface.mesh.core import vertex_normals
    from geoface.mesh.raster import rasterize_mesh
    from geoface.progress import StepProgress

    t0 = time.perf_counter()
    frames = np.asarray(frames, np.float32)
    T = len(track)
    if frames.shape[:3] != (T, track.image_size[1], track.image_size[0]) or len(masks) != T:
        raise GeofaceError(f"refine: frames {frames.shape} and masks do not fit the track ({T} frames of "
                           f"{track.image_size[0]}×{track.image_size[1]})")
    v = model_view()
    samp, Fskin = _face_samples()
    Bs = v.expression_modes[:, samp].astype(np.float64) * CM_TO_M  # (53, ns, 3)
    mean, Bid, Bex = point_bases()
    conf = mediapipe_on_ict()["confidence"]
    cam = track.camera()
    f, (cx, cy) = track.focal, track.centre
    E, R, tt = track.expressions.copy(), track.R.copy(), track.t.copy()
    neutral = track.neutral()
    width = None
    if points is not None:
        P = np.asarray(points, np.float64)
        width = np.linalg.norm(P[:, CHEEKS[0]] - P[:, CHEEKS[1]], axis=-1)
        okp = np.isfinite(P).all((1, 2)) & track.found
        base_pts = mean + np.tensordot(track.identity, Bid[: len(track.identity)], axes=1)

    # the expression modes as one (53, 3n) matrix in metres, made once (a blend per frame is then
    # one product, not a reshaped copy of the modes)
    modes = np.ascontiguousarray(v.expression_modes.reshape(len(v.expression_modes), -1), np.float64) * CM_TO_M
    # the faces around the sampled vertices: their normals are all the visibility test needs
    Fsamp = v.F[np.isin(v.F, samp).any(1)]

    def posed_all(k):
        X = neutral + (E[k] @ modes).reshape(-1, 3)
        return X @ R[k].T + tt[k]

    def visible(k):
        """(visible samples, their cosines to the view, the posed head)."""
        Vc = posed_all(k)
        # only the triangles that face the camera can hide a face vertex (half the z-buffer's work)
        P0 = Vc[Fskin[:, 0]]
        front = (np.cross(Vc[Fskin[:, 1]] - P0, Vc[Fskin[:, 2]] - P0) * P0).sum(1) < 0
        face, _, depth = rasterize_mesh(Vc, Fskin[front], cam)
        Xs = Vc[samp]
        uv = np.stack([f * Xs[:, 0] / Xs[:, 2] + cx, f * Xs[:, 1] / Xs[:, 2] + cy], 1)
        H, W = depth.shape
        px = np.floor(uv).astype(int)
        ins = (px[:, 0] >= 1) & (px[:, 0] < W - 1) & (px[:, 1] >= 1) & (px[:, 1] < H - 1)
        i, j = np.clip(px[:, 1], 0, H - 1), np.clip(px[:, 0], 0, W - 1)
        N = vertex_normals(Vc, Fsamp)[samp]
        cos = -(N * Xs).sum(1) / np.linalg.norm(Xs, axis=1)
        vis = ins & (Xs[:, 2] <= depth[i, j] + 2e-3) & (cos > 0.3) & (masks[k][i, j] > 0.5)
        return vis, cos, Vc

    def texture():
        acc, wsum = np.zeros((len(samp), 3)), np.zeros(len(samp))
        for k in range(0, T, max(1, T // 40)):
            vis, cos, Vc = visible(k)
            Xs = Vc[samp]
            uv = np.stack([f * Xs[:, 0] / Xs[:, 2] + cx, f * Xs[:, 1] / Xs[:, 2] + cy], 1)
            w = np.where(vis, cos ** 2, 0.0)
            acc += w[:, None] * _bilinear(frames[k], uv)
            wsum += w
        ok = wsum > 1e-6
        return np.where(ok[:, None], acc / np.maximum(wsum, 1e-9)[:, None], 0.0), ok

    def photo_error(col, seen):
        out = np.full(T, np.nan)
        for k in range(T):
            vis, _, Vc = visible(k)
            vis &= seen
            if vis.sum() < 50:
                continue
            Xs = Vc[samp][vis]
            uv = np.stack([f * Xs[:, 0] / Xs[:, 2] + cx, f * Xs[:, 1] / Xs[:, 2] + cy], 1)
            I = _bilinear(frames[k], uv)
            # the frame's own gain and offset per channel, fitted (as the refinement does)
            for c in range(3):
                A = np.c_[I[:, c], np.ones(len(I))]
                g = np.linalg.lstsq(A, col[vis, c], rcond=None)[0]
                I[:, c] = A @ g
            out[k] = float(np.abs(I - col[vis]).mean())
        return out

    col, seen = texture()
    before = photo_error(col, seen)
    bar = StepProgress(passes * len(blur) * T, "refining against the pixels", quiet=quiet, unit="frames")
    try:
        for _ in range(passes):
            for sigma in blur:
                imgs = np.stack([gaussian_filter(fr, (sigma, sigma, 0)) for fr in frames]) if sigma > 0 else frames
                gy, gx = np.gradient(imgs, axis=(1, 2))
                E_nb, t_nb = E.copy(), tt.copy()
                q = Rotation.from_matrix(R).as_quat()
                for k in range(T):
                    vis = visible(k)[0]
                    vis &= seen
                    if vis.sum() < 50:
                        bar.update(1)
                        continue
                    nb = [j for j in (k - 1, k + 1) if 0 <= j < T]
                    qn = np.mean([q[j] * np.sign(q[j] @ q[k]) for j in nb], 0)
                    R_nb = Rotation.from_quat(qn / np.linalg.norm(qn)).as_matrix()
                    e_nb = np.mean([E_nb[j] for j in nb], 0)
                    tr_nb = np.mean([t_nb[j] for j in nb], 0)
                    gain = np.ones(3)
                    off = np.zeros(3)
                    Bv = Bs[:, vis]  # (53, n, 3): the visible samples' modes, taken once per frame
                    Bv2 = Bv.reshape(len(Bv), -1)
                    base_v = neutral[samp][vis]
                    for _it in range(iterations):
                        Xc0 = base_v + (E[k] @ Bv2).reshape(-1, 3)
                        RX = Xc0 @ R[k].T
                        Xc = RX + tt[k]
                        z = Xc[:, 2]
                        uv = np.stack([f * Xc[:, 0] / z + cx, f * Xc[:, 1] / z + cy], 1)
                        I = _bilinear(imgs[k], uv)
                        Gx, Gy = _bilinear(gx[k], uv), _bilinear(gy[k], uv)
                        n = len(z)
                        du = _pixel_jacobian(f, RX, Xc, Bv, R[k])
                        # r_c = gain_c I_c(u) + off_c − col_c
                        Jg = (gain[None, :, None] * (Gx[..., None] * du[:, None, 0] + Gy[..., None] * du[:, None, 1]))
                        J = np.zeros((n, 3, 65))
                        J[..., :59] = Jg
                        J[:, np.arange(3), 59 + np.arange(3)] = I
                        J[:, np.arange(3), 62 + np.arange(3)] = 1.0
                        # colour differences in units of their noise (0.05), Cauchy-weighted
                        # (highlights, hair over a brow); the mean over the samples
                        r = ((gain * I + off - col[vis]) / _COLOUR_NOISE).reshape(-1)
                        J = J.reshape(-1, 65) / _COLOUR_NOISE
                        wr = 1.0 / (1.0 + r ** 2) / len(r)
                        Jw = J * wr[:, None]
                        Hm = Jw.T @ J
                        g = Jw.T @ r
                        if width is not None and okp[k]:  # the landmarks, as in the fit
                            Xl = base_pts + np.tensordot(E[k], Bex, axes=1) + view_offsets(R[k:k + 1], tt[k:k + 1],
                                                                                            mean.mean(0))[0]
                            RXl = Xl @ R[k].T
                            Xcl = RXl + tt[k]
                            zl = Xcl[:, 2]
                            ul = np.stack([f * Xcl[:, 0] / zl + cx, f * Xcl[:, 1] / zl + cy], 1)
                            rl = ul - P[k]
                            sc2 = (0.01 * width[k]) ** 2
                            wl = w_landmarks * conf / (1 + (rl ** 2).sum(1) / sc2) / sc2 / conf.sum()
                            Jl = _pixel_jacobian(f, RXl, Xcl, Bex, R[k]).reshape(-1, 59)
                            Jlw = Jl * np.repeat(wl, 2)[:, None]
                            Hm[:59, :59] += Jlw.T @ Jl
                            g[:59] += Jlw.T @ rl.reshape(-1)
                        # the neighbours (temporal smoothness), as in the fit
                        ws = w_smooth
                        dr = Rotation.from_matrix(R[k] @ R_nb.T).as_rotvec()
                        d2 = max(float(tt[k, 2]), 1e-3) ** 2
                        Hm[np.arange(3), np.arange(3)] += ws
                        Hm[np.arange(3, 6), np.arange(3, 6)] += ws / d2
                        g[0:3] += ws * dr
                        g[3:6] += ws * (tt[k] - tr_nb) / d2
                        Hm[np.arange(6, 59), np.arange(6, 59)] += ws
                        g[6:59] += ws * (E[k] - e_nb)
                        Hm[np.arange(65), np.arange(65)] += 1e-3 * np.diag(Hm) + 1e-9
                        x = -np.linalg.solve(Hm, g)
                        R[k] = _expmap(x[None, :3])[0] @ R[k]
                        tt[k] = tt[k] + x[3:6]
                        E[k] = np.clip(E[k] + x[6:59], 0, 1)
                        gain, off = gain + x[59:62], off + x[62:65]
                    bar.update(1)
            col, seen = texture()
    finally:
        bar.close()
    after = photo_error(col, seen)
    out = HeadTrack(identity=track.identity, expressions=E, expression_names=track.expression_names, R=R, t=tt,
                    focal=track.focal, centre=track.centre, image_size=track.image_size, found=track.found,
                    residual_px=track.residual_px, seconds=track.seconds + time.perf_counter() - t0,
                    settings=track.settings)
    return out, Refinement(before, after, time.perf_counter() - t0)
