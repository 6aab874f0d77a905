"""Where is the face on a mesh: the search's views, the face detector's candidates looked at a
second time, and a first guess of the face's centre, frame and size from the detector's key
points (:mod:`geoface.track.scan` refines it)."""
from __future__ import annotations

import numpy as np

from .face3d import keypoint_frame
from .look import any_up, camera_at, lift, principal_frame, search_views, unit, unrotate

__all__ = ["search", "verified", "guess", "guess_2d", "FACE_SHARE", "VERIFY", "FACE_HALF"]

#: the face's box (the detector's) covers this share of a second look's width
FACE_SHARE = 0.5
#: the search's candidates looked at a second time
VERIFY = 10
#: the refined views' half width over the face's height (nasion to chin)
FACE_HALF = 1.25


def search(look, res, *, mosaic: bool = True):
    """The search's views where the detector finds a face, best first: ``[(score, key points
    (6, 2), box, camera, face, depth)]``, one a view and turn of the image. ``mosaic``: the four
    turns of a view are looked at in one image (a 2 × 2 mosaic: the full-range detector finds
    small faces, and one call costs a quarter of four); else one by one."""
    c, radius, E = principal_frame(look.V, look.F)
    out = []
    for g in search_views():
        # the view and its up are taken in the surface's principal frame: a turned copy is seen
        # the same (up to resampling), not rolled by as much as 45 degrees between the four turns
        out += _look_round(look, camera_at(c, E @ g, E @ any_up(g), radius, res), res, mosaic)
    return sorted(out, key=lambda x: -x[0])


def _look_round(look, cam, res, mosaic):
    """The best face the detector finds on each quarter turn of one view's render."""
    img, face, depth = look.render(cam)
    if (face >= 0).mean() < 0.01:
        return []
    best: dict = {}
    if mosaic:
        tiles = np.zeros((2 * res, 2 * res, 3), np.uint8)
        for k in range(4):
            i, j = divmod(k, 2)
            tiles[i * res:(i + 1) * res, j * res:(j + 1) * res] = np.rot90(img, k)
        found = []
        for score, kp, box in look.detect_all(tiles):
            i, j = min(int((box[1] + 0.5 * box[3]) // res), 1), min(int((box[0] + 0.5 * box[2]) // res), 1)
            found.append((2 * i + j, score, kp - np.array([j * res, i * res], np.float64), box))
    else:
        found = [(k, sc, kp, box) for k in range(4) for sc, kp, box in look.detect_all(np.ascontiguousarray(np.rot90(img, k)))]
    for k, score, kp, box in found:
        if k not in best or score > best[k][0]:
            best[k] = (score, unrotate(kp, k, res), np.array([0.0, 0.0, box[2], box[3]]), cam, face, depth)
    return list(best.values())


def verified(look, found, res, *, tries: int = VERIFY):
    """The search's best ``tries`` candidates, each looked at again: zoomed on the face the
    detector saw and turned upright by its key points. ``[(the detector's score on that second
    look, the guess from its key points)]``, best first, one a face (guesses that look within 25
    degrees of a better one's way are dropped). A face seen so scores high; the detector's false
    alarms on a search view (an ear, the back of a head at an angle) do not."""
    out = []
    for cand in found[:tries]:
        g2 = guess_2d(look, cand)
        g3 = guess(look, cand, fallback=g2)
        for g in (g3,) if g3 is g2 else (g3, g2):
            cam = camera_at(*g, res)
            img, face, depth = look.render(cam)
            d = look.detect(img)
            if d is not None:
                out.append((d[0], guess(look, (d[0], d[1], d[2], cam, face, depth))))
                break
    out.sort(key=lambda x: -x[0])
    kept: list = []
    for sc, g in out:
        if not any(g[1] @ k[1][1] > np.cos(np.radians(25.0)) for k in kept):
            kept.append((sc, g))
    return kept


def guess(look, cand, fallback=None):
    """Centre, front, up and half-size of the face from the detector's key points on a view (right
    eye, left eye, nose tip, mouth: the subject's) lifted onto the surface: the face's own frame,
    however obliquely the view saw it; where they cannot be lifted or do not look like a face's,
    ``fallback`` (default :func:`guess_2d`)."""
    score, kp, box, cam, face, depth = cand
    size = max(box[2], box[3])
    X = lift(kp[:4], cam, face, look.V, look.F, depth=depth, window=max(2, int(0.08 * size)),
             gap=np.inf if not np.isfinite(depth).any() else 0.3 * size / cam.fx * float(np.min(depth)))
    towards = -cam.R[2]  # from the surface towards the camera
    if np.isfinite(X).all():
        right, up, front = keypoint_frame(X)
        if front @ towards < 0:  # the key points seen mirrored
            right, up, front = -right, up, -front
        eyes = float(np.linalg.norm(X[1] - X[0]))
        box_world = size / cam.fx * float((X[2] - cam.center) @ -towards)
        # the eyes' centres lie about 0.4 of the detector's box apart: else a key point missed
        if front @ towards > 0.2 and 0.2 < eyes / max(box_world, 1e-300) < 0.7:
            return X[2], front, up, FACE_HALF * 2.0 * eyes  # the face's height: about twice the eyes' distance
    return guess_2d(look, cand) if fallback is None else fallback


def guess_2d(look, cand):
    """Centre, front, up and half-size of the face from the detector's key points on a view, in
    the image alone: the view's direction, the eyes' and mouth's roll, the box's size, the centre
    on the surface under the nose."""
    score, kp, box, cam, face, depth = cand
    Rt = cam.R.T  # camera axes in the world: columns x right, y down, z forward
    eye_r, eye_l, nose, mouth = kp[0], kp[1], kp[2], kp[3]
    towards = -Rt[:, 2]
    y_img = unit(0.5 * (eye_l + eye_r) - mouth)  # up in the image (y down)
    up = unit(Rt @ np.array([y_img[0], y_img[1], 0.0]))
    up = unit(up - (up @ towards) * towards)
    X = lift(np.array([nose]), cam, face, look.V, look.F)
    if np.isfinite(X).all():
        center = X[0]
    else:  # the nose's pixel shows nothing: the ray through it, at the surface's centre's depth
        ray = unit(Rt @ np.array([(nose[0] - cam.cx) / cam.fx, (nose[1] - cam.cy) / cam.fy, 1.0]))
        center = cam.center + float(np.linalg.norm(look.V.mean(0) - cam.center)) * ray
    depth_c = float(np.linalg.norm(center - cam.center))
    return center, towards, up, 0.5 * max(box[2], box[3]) / cam.fx * depth_c / FACE_SHARE
