"""The ICT head track refined against the pixels (:func:`refine_photometric`)."""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from geoface.errors import GeofaceError
from geoface.track.head_solver import expmap as _expmap, skew as _skew
from geoface.track.head_track import (CM_TO_M, CHEEKS, HeadTrack, point_bases, model_view, mediapipe_on_ict,
                                      neutral_head, view_offsets)

__all__ = ["refine_photometric", "Refinement", "albedo_and_light"]

log = logging.getLogger(__name__)


#: the colour noise the photometric term expects (RGB in [0, 1]): its residuals' unit
_COLOUR_NOISE = 0.05
#: the frames' encoding: light adds up in ``value ** GAMMA`` (sRGB's curve, near enough)
GAMMA = 2.2


def _sh9(N):
    """The nine real spherical harmonics up to order 2 (constants left out: the lighting that
    multiplies them is fitted) at unit normals ``N (n, 3)``: a distant light's Lambertian shading
    is within a few percent of a combination of them (Ramamoorthi & Hanrahan 2001)."""
    x, y, z = N[:, 0], N[:, 1], N[:, 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, x * z, y * z, x * x - y * y, 3 * z * z - 1], 1)


@dataclass(frozen=True)
class Refinement:
    """What :func:`refine_photometric` measured: per frame the photometric error (mean absolute
    RGB difference over the visible face, in [0, 1] units) of the track before and after, and the
    seconds it took."""

    before: np.ndarray
    after: np.ndarray
    seconds: float


#: the lighting that leaves colours as they are (the constant harmonic alone)
_UNLIT = np.eye(9, 3)[:, [0, 0, 0]]


def _shading(N, light):
    """Linear-light shading ``(n, 3)`` of unit normals ``N (n, 3)`` under ``light (9, 3)``."""
    return np.maximum(_sh9(N) @ light, 1e-3)


def albedo_and_light(views, n: int, *, shading: bool = True, rounds: int = 3):
    """The albedo of ``n`` points and the lighting (nine harmonics per channel, :func:`_sh9`) that
    best explain what the frames saw, fitted in turn by least squares (``rounds`` times) from the
    constant light. ``views``: per frame ``(seen (n,) bool, weight (m,), normals (m, 3), colours
    (m, 3) in linear light)`` of the ``m`` points it saw. Returns ``(albedo (n, 3), ok (n,) seen at
    all, light (9, 3))``; ``shading=False``: the constant light, the albedo the weighted mean."""
    light = _UNLIT.copy()
    for rnd in range(rounds if shading else 1):
        acc, wsum = np.zeros((n, 3)), np.zeros((n, 3))
        for vis, w, N, I in views:
            s_ = _shading(N, light)
            acc[vis] += w[:, None] * I * s_
            wsum[vis] += w[:, None] * s_ * s_
        ok = wsum[:, 0] > 1e-9
        alb = np.where(ok[:, None], acc / np.maximum(wsum, 1e-12), 0.0)
        if not shading or rnd == rounds - 1:
            break
        H = np.zeros((3, 9, 9))
        b = np.zeros((3, 9))
        for vis, w, N, I in views:
            Y = _sh9(N)
            a = alb[vis]
            for c in range(3):
                A = Y * a[:, c:c + 1]
                H[c] += (A * w[:, None]).T @ A
                b[c] += (A * w[:, None]).T @ I[:, c]
        # a little ridge on the changing harmonics: a lighting the frames cannot tell stays flat
        ridge = np.diag([0, 1, 1, 1, 4, 4, 4, 4, 4]) * 1e-3 * np.trace(H.mean(0)) / 9 + 1e-12 * np.eye(9)
        light = np.stack([np.linalg.solve(H[c] + ridge, b[c]) for c in range(3)], 1)
    return alb, ok, light


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


def _project(f, Xc, dX):
    """How the image positions of points ``Xc (n, 3)`` (camera) move, ``(n, 2, m)``, when the
    points move by ``dX (n, 3, m)``: the projection's 2×3 derivative applied written out (its zeros
    skipped: batched 2×3 products are slow)."""
    z = Xc[:, 2]
    a, bx, by = f / z, -f * Xc[:, 0] / z ** 2, -f * Xc[:, 1] / z ** 2
    return np.stack([a[:, None] * dX[:, 0] + bx[:, None] * dX[:, 2], a[:, None] * dX[:, 1] + by[:, None] * dX[:, 2]], 1)


def _pixel_jacobian(f, RX, Xc, B, R):
    """How points move in the image, ``(n, 2, 6 + m)``, under a frame's unknowns (a turn, a shift,
    the ``m`` weights of the modes ``B (m, n, 3)``, given in the head's frame): points ``Xc (n, 3)``
    in the camera, ``RX`` the same before the shift, ``R`` the head's turn, ``f`` the focal length."""
    dX = np.empty((len(Xc), 3, 6 + len(B)))
    dX[..., 0:3] = -_skew(RX)
    dX[..., 3:6] = np.eye(3)
    dX[..., 6:] = (B @ R.T).transpose(1, 2, 0)
    return _project(f, Xc, dX)


def _mode_jacobian(f, Xc, B, R):
    """How points move in the image, ``(n, 2, m)``, under the weights of modes ``B (m, n, 3)``."""
    return _project(f, Xc, (B @ R.T).transpose(1, 2, 0))


def refine_photometric(track: HeadTrack, frames, masks, points=None, *, passes: int = 3, iterations: int = 4,
                       blur=(1.0, 0.5, 0.25, 0.0), w_landmarks: float = 0.05, w_smooth: float = 0.5, shading: bool = True,
                       identity: bool = True, w_identity: float = 1e-3, region=None,
                       quiet: bool | None = None) -> tuple[HeadTrack, Refinement]:
    """The track refined against the pixels: each frame's pose and expressions moved so that the
    head's colours (taken from the frames themselves) match the frame where the head is seen — a
    dense, direct alignment of the face's texture (as analysis-by-synthesis trackers do), by
    Gauss–Newton on the visible face vertices (a z-buffer decides which), coarse to fine over
    ``blur`` (Gaussian σ in pixels; 0: the frame as it is; the finest levels align the sharp
    edges — lids, lips, brows — to a fraction of a pixel; chosen on the validation people of
    ``bench/bench_head_track.py`` against 2 then 1 px), with each frame's colour gain and offset
    per channel, the landmarks (``points``, the face mesh's 468 as fitted, weight ``w_landmarks``) and the
    neighbours' poses and expressions (``w_smooth``) keeping it in place.

    The head's colours are an albedo per point lit by one lighting for the clip (``shading``:
    second-order spherical harmonics per channel in linear light, fixed to the camera as a room's
    lights are; as the face models of DECA and Face2Face light theirs), so that a face turning
    under a lamp is not pulled to where the frames' average shading would put it; albedo and
    lighting are fitted in turn, and taken again after each of ``passes`` passes.
    ``shading=False``: one colour per point, the frames' average.

    ``identity``: after each sweep over the frames, one Gauss–Newton step of the clip's identity
    weights (the face's shape) with every frame's unknowns eliminated, as bundle adjustment takes
    it; ``w_identity`` is its N(0, 1) prior per frame. ``identity=False`` keeps the identity the
    landmarks gave. ``frames (T, H, W, 3)`` float in [0, 1] (sRGB), ``masks (T, H, W)`` the person
    (where a headset hides the upper face, the person less the headset). ``points`` may be NaN
    where a point is not seen (under a headset): those points have no weight. ``region``: a bool
    per head vertex (:data:`~geoface.track.head_track.ICT_TRACK_PARTS`) that keeps the pixels looked
    at to that part of the face (the face below a headset:
    :func:`~geoface.track.head_track.below_headset`), so that nothing above it steers the track.
    Returns the refined track and the errors before and after."""
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
    if region is not None:  # only part of the face is looked at (the face below a headset)
        region = np.asarray(region, bool).reshape(-1)
        if region.shape != (len(v.expression_modes[0]),):
            raise GeofaceError(f"refine: region must be a bool per head vertex ({len(v.expression_modes[0])}); got {region.shape}")
        samp = samp[region[samp]]
        if len(samp) < 100:
            raise GeofaceError(f"refine: the region keeps {len(samp)} of the face's samples; at least 100 are needed")
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
        if P.shape != (T, 468, 2):
            raise GeofaceError(f"refine: points must be (T, 468, 2) for the track's {T} frames; got {P.shape}")
        seen_pt = np.isfinite(P).all(2)  # a point not seen (NaN: under a headset, off the frame) has no weight
        okp = (seen_pt.sum(1) >= 20) & track.found
        P = np.where(seen_pt[..., None], P, 0.0)
        # the landmarks' robust scale: the cheeks' distance, or where a cheek is not seen, the track's own
        width = np.linalg.norm(P[:, CHEEKS[0]] - P[:, CHEEKS[1]], axis=-1)
        hid = ~seen_pt[:, CHEEKS].all(1)
        if hid.any():
            fitted = track.points()
            width[hid] = np.linalg.norm(fitted[hid, CHEEKS[0]] - fitted[hid, CHEEKS[1]], axis=-1)
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
        """(visible samples, their cosines to the view, the posed head, the samples' normals)."""
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
        return vis, cos, Vc, N

    # the head's colours: an albedo per sample, lit by one lighting for the clip (nine spherical
    # harmonics per channel, fixed to the camera as a room's lights are), in linear light;
    # ``shading=False`` keeps the light constant (a colour per sample, as the frames average it)
    light = _UNLIT

    def lit(N):
        return _shading(N, light)

    def texture():
        nonlocal light
        views = []
        for k in range(0, T, max(1, T // 40)):
            vis, cos, Vc, N = visible(k)
            Xs = Vc[samp][vis]
            uv = np.stack([f * Xs[:, 0] / Xs[:, 2] + cx, f * Xs[:, 1] / Xs[:, 2] + cy], 1)
            views.append((vis, cos[vis] ** 2, N[vis], _bilinear(frames[k], uv) ** GAMMA))
        alb, ok, light = albedo_and_light(views, len(samp), shading=shading)
        return alb, ok

    def predict(alb, vis, N):
        """The head's colours (sRGB) at the visible samples, lit as the frame sees them."""
        return np.clip(alb[vis] * lit(N[vis]), 0, 1) ** (1 / GAMMA)

    def photo_error(alb, seen):
        out = np.full(T, np.nan)
        for k in range(T):
            vis, _, Vc, N = visible(k)
            vis &= seen
            if vis.sum() < 50:
                continue
            Xs = Vc[samp][vis]
            uv = np.stack([f * Xs[:, 0] / Xs[:, 2] + cx, f * Xs[:, 1] / Xs[:, 2] + cy], 1)
            I = _bilinear(frames[k], uv)
            target = predict(alb, vis, N)
            # the frame's own gain and offset per channel, fitted (as the refinement does)
            for c in range(3):
                A = np.c_[I[:, c], np.ones(len(I))]
                g = np.linalg.lstsq(A, target[:, c], rcond=None)[0]
                I[:, c] = A @ g
            out[k] = float(np.abs(I - target).mean())
        return out

    col, seen = texture()
    before = photo_error(col, seen)
    na = len(track.identity)
    ident = np.asarray(track.identity, np.float64).copy()
    Bid_s = v.identity_modes[:na, samp].astype(np.float64) * CM_TO_M  # (na, ns, 3)

    def frame_setup(k, E_nb, t_nb, q):
        """A frame's visible samples, their colours as lit there, and its neighbours' pose and
        expressions (taken at the start of the sweep); None where too little of the face is seen."""
        vis, _, _, Nk = visible(k)
        vis &= seen
        if vis.sum() < 50:
            return None
        nb = [j for j in (k - 1, k + 1) if 0 <= j < T]
        qn = np.mean([q[j] * np.sign(q[j] @ q[k]) for j in nb], 0)
        R_nb = Rotation.from_quat(qn / np.linalg.norm(qn)).as_matrix()
        Bv = Bs[:, vis]  # (53, n, 3): the visible samples' modes, taken once per frame
        return {"vis": vis, "Bv": Bv, "Bv2": Bv.reshape(len(Bv), -1), "R_nb": R_nb,
                "e_nb": np.mean([E_nb[j] for j in nb], 0), "tr_nb": np.mean([t_nb[j] for j in nb], 0),
                "target": predict(col, vis, Nk)}  # its shading at the pose the frame starts from

    def frame_system(k, st, imgs, gx, gy, gain, off, with_identity=False):
        """Frame ``k``'s Gauss–Newton system in its 65 unknowns (turn, shift, 53 expressions, gain
        and offset per channel): ``(H, g, identity blocks)``; the blocks (``H_aa``, ``H_xa``,
        ``g_a``: how its terms see the shared identity weights) only ``with_identity``."""
        vis, Bv = st["vis"], st["Bv"]
        Xc0 = neutral[samp][vis] + (E[k] @ st["Bv2"]).reshape(-1, 3)
        RX = Xc0 @ R[k].T
        Xc = RX + tt[k]
        z = Xc[:, 2]
        uv = np.stack([f * Xc[:, 0] / z + cx, f * Xc[:, 1] / z + cy], 1)
        I = _bilinear(imgs[k], uv)
        Gx, Gy = _bilinear(gx[k], uv), _bilinear(gy[k], uv)
        n = len(z)
        du = _pixel_jacobian(f, RX, Xc, Bv, R[k])
        # r_c = gain_c I_c(u) + off_c − col_c
        J = np.zeros((n, 3, 65))
        J[..., :59] = gain[None, :, None] * (Gx[..., None] * du[:, None, 0] + Gy[..., None] * du[:, None, 1])
        J[:, np.arange(3), 59 + np.arange(3)] = I
        J[:, np.arange(3), 62 + np.arange(3)] = 1.0
        # colour differences in units of their noise (0.05), Cauchy-weighted (highlights, hair
        # over a brow); the mean over the samples
        r = ((gain * I + off - st["target"]) / _COLOUR_NOISE).reshape(-1)
        J = J.reshape(-1, 65) / _COLOUR_NOISE
        wr = 1.0 / (1.0 + r ** 2) / len(r)
        Jw = J * wr[:, None]
        Hm = Jw.T @ J
        g = Jw.T @ r
        blocks = None
        if with_identity:
            dua = _mode_jacobian(f, Xc, Bid_s[:, vis], R[k])
            Ja = (gain[None, :, None] * (Gx[..., None] * dua[:, None, 0] + Gy[..., None] * dua[:, None, 1]))
            Ja = Ja.reshape(-1, na) / _COLOUR_NOISE
            blocks = [(Ja * wr[:, None]).T @ Ja, Jw.T @ Ja, (Ja * wr[:, None]).T @ r]
        if width is not None and okp[k]:  # the landmarks, as in the fit
            Xl = base_pts + np.tensordot(E[k], Bex, axes=1) + view_offsets(R[k:k + 1], tt[k:k + 1], mean.mean(0))[0]
            RXl = Xl @ R[k].T
            Xcl = RXl + tt[k]
            zl = Xcl[:, 2]
            ul = np.stack([f * Xcl[:, 0] / zl + cx, f * Xcl[:, 1] / zl + cy], 1)
            rl = ul - P[k]
            sc2 = (0.01 * width[k]) ** 2
            wl = np.repeat(w_landmarks * conf * seen_pt[k] / (1 + (rl ** 2).sum(1) / sc2) / sc2 / conf.sum(), 2)
            Jl = _pixel_jacobian(f, RXl, Xcl, Bex, R[k]).reshape(-1, 59)
            Jlw = Jl * wl[:, None]
            Hm[:59, :59] += Jlw.T @ Jl
            g[:59] += Jlw.T @ rl.reshape(-1)
            if with_identity:
                Jla = _mode_jacobian(f, Xcl, Bid[:na], R[k]).reshape(-1, na)
                blocks[0] += (Jla * wl[:, None]).T @ Jla
                blocks[1][:59] += Jlw.T @ Jla
                blocks[2] += (Jla * wl[:, None]).T @ rl.reshape(-1)
        # the neighbours (temporal smoothness), as in the fit
        ws = w_smooth
        dr = Rotation.from_matrix(R[k] @ st["R_nb"].T).as_rotvec()
        d2 = max(float(tt[k, 2]), 1e-3) ** 2
        Hm[np.arange(3), np.arange(3)] += ws
        Hm[np.arange(3, 6), np.arange(3, 6)] += ws / d2
        g[0:3] += ws * dr
        g[3:6] += ws * (tt[k] - st["tr_nb"]) / d2
        Hm[np.arange(6, 59), np.arange(6, 59)] += ws
        g[6:59] += ws * (E[k] - st["e_nb"])
        Hm[np.arange(65), np.arange(65)] += 1e-3 * np.diag(Hm) + 1e-9
        return Hm, g, blocks

    def step(k, x, gain, off):
        R[k] = _expmap(x[None, :3])[0] @ R[k]
        tt[k] = tt[k] + x[3:6]
        E[k] = np.clip(E[k] + x[6:59], 0, 1)
        return gain + x[59:62], off + x[62:65]

    def identity_step(kept, imgs, gx, gy):
        """One Gauss–Newton step of the clip's identity weights with every frame's unknowns
        eliminated (the Schur complement, as bundle adjustment takes it) and then moved with
        it: the face's shape from all the frames' pixels at once, the N(0, 1) prior
        (``w_identity`` per frame) keeping it among the model's people."""
        Haa = np.eye(na) * w_identity * len(kept)
        ga = w_identity * len(kept) * ident
        solved = {}
        for k, (st, gain, off) in kept.items():
            Hm, g, (H_aa, H_xa, g_a) = frame_system(k, st, imgs, gx, gy, gain, off, with_identity=True)
            Y = np.linalg.solve(Hm, np.c_[H_xa, g])
            Haa += H_aa - H_xa.T @ Y[:, :na]
            ga += g_a - H_xa.T @ Y[:, na]
            solved[k] = (Y, gain, off)
        Haa[np.arange(na), np.arange(na)] *= 1 + 1e-3
        da = -np.linalg.solve(Haa, ga)
        log.debug("identity step: |da| %.3f, prior %.3g of the data's mean diagonal %.3g", np.linalg.norm(da),
                  w_identity * len(kept), (np.trace(Haa) / na - w_identity * len(kept)))
        for k, (Y, gain, off) in solved.items():
            step(k, -(Y[:, na] + Y[:, :na] @ da), gain, off)
        ident[:] += da
        neutral[:] = neutral_head(ident, v)
        if width is not None:
            base_pts[:] = mean + np.tensordot(ident, Bid[:na], axes=1)

    bar = StepProgress(passes * len(blur) * T, "refining against the pixels", quiet=quiet, unit="frames")
    try:
        for _ in range(passes):
            for sigma in blur:
                imgs = np.stack([gaussian_filter(fr, (sigma, sigma, 0)) for fr in frames]) if sigma > 0 else frames
                gy, gx = np.gradient(imgs, axis=(1, 2))
                E_nb, t_nb = E.copy(), tt.copy()
                q = Rotation.from_matrix(R).as_quat()
                kept = {}
                for k in range(T):
                    st = frame_setup(k, E_nb, t_nb, q)
                    if st is None:
                        bar.update(1)
                        continue
                    gain, off = np.ones(3), np.zeros(3)
                    for _it in range(iterations):
                        Hm, g, _ = frame_system(k, st, imgs, gx, gy, gain, off)
                        gain, off = step(k, -np.linalg.solve(Hm, g), gain, off)
                    kept[k] = (st, gain, off)
                    bar.update(1)
                if identity and kept:
                    identity_step(kept, imgs, gx, gy)
            col, seen = texture()
    finally:
        bar.close()
    after = photo_error(col, seen)
    out = HeadTrack(identity=ident if identity else track.identity, expressions=E, expression_names=track.expression_names, R=R, t=tt,
                    focal=track.focal, centre=track.centre, image_size=track.image_size, found=track.found,
                    residual_px=track.residual_px, seconds=track.seconds + time.perf_counter() - t0,
                    settings=track.settings)
    return out, Refinement(before, after, time.perf_counter() - t0)
