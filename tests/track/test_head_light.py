"""The head's colours in the photometric refinement: an albedo per point under one lighting."""
import functools

import numpy as np

from geoface.rotations import euler_rotation, rotation_vector
from geoface.track.head_refine import albedo_and_light
from geoface.track.head_track import fit_head_track, mediapipe_on_ict


def _lit_sphere_views(light_dir, frames=9, n=600, seed=0, shift=0.0):
    """A sphere of ``n`` points with random albedos turning ±30° under a fixed lamp and a little
    ambient light (Lambert's law, clamped): per frame the points facing the camera (+z)."""
    rng = np.random.default_rng(seed)
    P = rng.standard_normal((n, 3))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    alb = rng.uniform(0.2, 0.8, (n, 3))
    ldir = np.asarray(light_dir, float) / np.linalg.norm(light_dir)
    views = []
    for yaw in np.linspace(-30, 30, frames) + shift:
        N = P @ euler_rotation(np.radians(yaw), 0.0, 0.0).T
        seen = N[:, 2] > 0.3
        shade = 0.15 + 0.85 * np.clip(N[seen] @ ldir, 0, None)
        views.append((seen, N[seen, 2] ** 2, N[seen], alb[seen] * shade[:, None]))
    return views, alb


def _relative_error(views, alb, light_fn):
    err = []
    for seen, _, N, I in views:
        err.append(np.abs(light_fn(seen, N) - I).mean() / I.mean())
    return float(np.mean(err))


def test_a_turning_head_under_a_lamp_is_explained_by_its_albedo_and_one_lighting():
    from geoface.track.head_refine import _shading

    views, alb = _lit_sphere_views([0.6, 0.3, 0.75])
    a, ok, light = albedo_and_light(views, len(alb))
    assert ok.mean() > 0.45  # the half of the sphere the camera sees, and a little more
    a0, _, _ = albedo_and_light(views, len(alb), shading=False)
    # the colours of poses between those fitted (what the refinement predicts for a frame)
    between, _ = _lit_sphere_views([0.6, 0.3, 0.75], frames=8, shift=3.75)
    between = [(s & ok, w[ok[s]], N[ok[s]], I[ok[s]]) for s, w, N, I in between]
    lit_err = _relative_error(between, alb, lambda s, N: a[s] * _shading(N, light))
    flat_err = _relative_error(between, alb, lambda s, N: a0[s])
    # nine harmonics hold a lamp's clamped cosine to a few percent (less well near the line
    # where its light ends); one colour per point cannot follow the shading as the sphere turns. (The albedo itself is known only up to a function
    # of the latitude, which turns about the vertical leave alone: the lighting takes the rest.)
    assert lit_err < 0.08, lit_err  # 6.3%: the harmonics round the lamp's terminator
    assert flat_err > 2 * lit_err, (flat_err, lit_err)  # 15%


def test_without_light_the_albedo_is_the_weighted_mean_of_what_was_seen():
    views, alb = _lit_sphere_views([0.0, 0.0, 1.0], frames=3)
    a, ok, light = albedo_and_light(views, len(alb), shading=False)
    assert np.allclose(light[0], 1.0) and np.allclose(light[1:], 0.0)
    i = np.flatnonzero(ok)[0]
    w = np.array([v[1][np.cumsum(v[0]) [i] - 1] if v[0][i] else 0.0 for v in views])
    c = np.array([v[3][np.cumsum(v[0])[i] - 1] if v[0][i] else np.zeros(3) for v in views])
    assert np.allclose(a[i], (w[:, None] * c).sum(0) / w.sum())


def test_the_identity_columns_are_the_derivative_of_the_projection():
    """The refinement's identity step moves the face's shape through how the modes move each
    point in the image (:func:`_mode_jacobian`): that is the derivative, by central differences."""
    from geoface.track.head_refine import _mode_jacobian

    rng = np.random.default_rng(3)
    X = rng.uniform(-0.08, 0.08, (30, 3)) + [0.0, 0.0, 0.6]
    B = rng.standard_normal((4, 30, 3)) * 0.01
    R = euler_rotation(0.2, -0.12, 0.05)
    f = 800.0

    def uv(w):
        Xc = X + np.tensordot(w, B, axes=1) @ R.T
        return f * Xc[:, :2] / Xc[:, 2:]

    J = _mode_jacobian(f, X, B, R)
    h = 1e-6
    for m in range(4):
        e = np.eye(4)[m] * h
        num = (uv(e) - uv(-e)) / (2 * h)
        assert np.allclose(J[:, :, m], num, rtol=1e-5, atol=1e-6)


@functools.lru_cache(maxsize=1)
def _turning_person():
    """A lit ICT person turning its head (6 frames at 160²) and its face-mesh points known to a
    pixel: ``(person, frames, masks, points, true turns in the camera)``."""
    from geoface.avatar.ict import ICTPerson

    person = ICTPerson(np.random.default_rng([5, 7201]), res=160, map_res=256, supersample=1)
    cam = person.cam
    tab = mediapipe_on_ict()
    frames, pts, Rs = [], [], []
    for k, yaw in enumerate(np.linspace(-18, 18, 6)):
        R = euler_rotation(np.radians(yaw), np.radians(4.0 * np.sin(k)), 0.0)
        V, rgb, alpha, _ = person.render({"jawOpen": 0.15 * (k % 2)}, R, np.zeros(3))
        frames.append(rgb * (alpha[..., None] > 0.5))
        Vc = V @ cam.R.T + cam.t
        X = np.einsum("kjd,kj->kd", Vc[tab["vertices"]], tab["weights"])
        pts.append(np.stack([cam.fx * X[:, 0] / X[:, 2] + cam.cx, cam.fy * X[:, 1] / X[:, 2] + cam.cy], 1))
        Rs.append(cam.R @ R)
    rng = np.random.default_rng(1)
    pts = np.stack(pts) + rng.normal(0, 1.0, (len(pts), 468, 2))  # a detector's pixel of noise
    frames = np.stack(frames).astype(np.float32)
    masks = (frames.max(-1) > 0).astype(np.float32)
    return person, frames, masks, pts, np.stack(Rs)


def _motion_error(Rf, Rs):
    """The head's turn from frame 0, against the truth's: mean degrees."""
    rel_f = np.einsum("tij,kj->tik", Rf, Rf[0])
    rel_t = np.einsum("tij,kj->tik", Rs, Rs[0])
    return np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", rel_f, rel_t) - 1) / 2, -1, 1))).mean()


def test_the_pixels_take_a_wrong_face_shape_towards_the_persons():
    """A lit ICT person turning its head, its face-mesh points known to a pixel, tracked from a
    face shape made wrong (six identity weights moved by 2–3σ): the refinement against the pixels
    takes the face's shape most of the way back to the person's, and keeps the head's turns."""
    import dataclasses

    from geoface.track.head_refine import refine_photometric

    person, frames, masks, pts, Rs = _turning_person()
    cam = person.cam
    tr = fit_head_track(pts, (160, 160), focal=cam.fx, quiet=True)
    wrong = tr.identity.copy()
    wrong[:6] += [3.0, -3.0, 2.5, -2.5, 2.0, -2.0]
    tr = dataclasses.replace(tr, identity=wrong)
    out, _ = refine_photometric(tr, frames, masks, pts, passes=2, blur=(1.0, 0.0), quiet=True)
    before, after = person.face_shape_error_mm(tr.neutral())[0], person.face_shape_error_mm(out.neutral())[0]
    assert after < 0.7 * before, (before, after)  # 6.5 → 4.1 mm

    assert _motion_error(out.R, Rs) < _motion_error(tr.R, Rs) + 0.3, (_motion_error(tr.R, Rs), _motion_error(out.R, Rs))
    # identity=False leaves the shape as the points gave it
    kept, _ = refine_photometric(tr, frames, masks, pts, passes=1, blur=(1.0,), identity=False, quiet=True)
    assert np.array_equal(kept.identity, tr.identity)


def test_a_face_below_a_headset_is_tracked_from_its_own_pixels_and_points():
    """The face below a headset (``region``: the head's vertices below the eyes; the points above
    them not seen, NaN): the refinement against those pixels brings the head's turns closer than
    the points below the eyes alone give them, and what lies above does not steer it (the upper
    face's pixels scrambled, the turns stay within a few hundredths of a degree)."""
    import pytest

    from geoface.errors import GeofaceError
    from geoface.track.head_refine import refine_photometric
    from geoface.track.head_track import below_headset

    person, frames, masks, pts, Rs = _turning_person()
    full = fit_head_track(pts, (160, 160), focal=person.cam.fx, quiet=True)
    lower, region = below_headset(full.identity)
    assert 150 < lower.sum() < 350 and 0.3 < region.mean() < 0.8, (lower.sum(), region.mean())
    hidden = np.where(lower[None, :, None], pts, np.nan)
    held = fit_head_track(pts, (160, 160), focal=person.cam.fx, use=lower, identity=full.identity, quiet=True)
    kw = dict(passes=1, blur=(1.0, 0.0), identity=False, region=region, quiet=True)
    out, ref = refine_photometric(held, frames, masks, hidden, **kw)
    assert np.nanmean(ref.after) < np.nanmean(ref.before)
    assert _motion_error(out.R, Rs) < _motion_error(held.R, Rs), (_motion_error(held.R, Rs), _motion_error(out.R, Rs))
    # the upper face's pixels scrambled: the rows more than 6 px above the points below the cut
    # (the blur's reach is 4σ)
    cut_rows = [int(np.min(held.points(k)[lower, 1])) - 6 for k in range(len(held))]
    noisy = frames.copy()
    rng = np.random.default_rng(2)
    for k, r in enumerate(cut_rows):
        noisy[k, :r] = rng.uniform(0, 1, noisy[k, :r].shape) * (masks[k, :r, :, None] > 0)
    again, _ = refine_photometric(held, noisy, masks, hidden, **kw)
    turn = np.degrees([np.linalg.norm(rotation_vector(a @ b.T)) for a, b in zip(again.R, out.R)])
    assert turn.max() < 0.05, turn
    with pytest.raises(GeofaceError, match="region"):
        refine_photometric(held, frames, masks, hidden, region=np.zeros_like(region), quiet=True)
