"""Where a headset hides the face in a video's frames (:func:`headset_masks`): its colour
learned in each frame where the face mesh puts the brows and eyes, or, without the face mesh's
points, a fixed test for grey or black plastic."""

from __future__ import annotations

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["headset_masks", "HEADSET_SEEDS"]


#: the iBUG points a headset hides, whatever its shape: the brows, the eyes' rims and the nose's
#: bridge (MediaPipe places them from the face below it: some fall on its lower edge or below)
HEADSET_SEEDS = (*range(17, 29), *range(36, 48))
#: points of the skin a headset leaves seen (iBUG pairs, midway: the cheeks beside the nose, the
#: chin below the lip)
SKIN_SAMPLES = ((31, 3), (35, 13), (57, 8))
#: floors of the colour spreads learned from a frame (chromaticity, log brightness): sensor and
#: codec noise on flat plastic, and its shading from front to side
HEADSET_SPREAD_FLOOR = (0.04, 0.25)
#: ... and caps (a headset's colour is one: the seeds' pixels off it, on hair or the eyes, do not widen it)
HEADSET_SPREAD_CAP = (0.1, 0.5)
#: a frame's headset is learned from its seeds' pixels unlike the skin (beyond the tolerance in
#: the skin's spreads, at least these: the skin round the eyes is not the cheeks' tone), and it
#: has one only where at least this share of them are
SKIN_SPREAD_FLOOR = (0.06, 0.5)
HEADSET_MIN_SHARE = 0.5
#: how far a headset reaches beyond the face mesh's points: a share of their box's width each
#: side and of its height above (a headset is wider than the face, and the points under it are
#: drawn together)
REACH = (0.5, 0.6)


def headset_masks(frames, *, points=None, max_saturation: float = 0.15, min_value: float = 0.06, close_px: int = 1,
                  tolerance: float = 3.0) -> np.ndarray:
    """Where a headset hides the face in each frame, from the pixels: ``(T, H, W)`` bool.

    With ``points`` ``(T, 468, 2)`` (MediaPipe's face-mesh points in pixels, as it places them
    under a headset too, from the face below it) the headset's colour is learned in each frame:
    the pixels at the brows, the eyes' rims and the nose's bridge (:data:`HEADSET_SEEDS`) that are
    unlike the skin at the cheeks and the chin (:data:`SKIN_SAMPLES`) give its chromaticity
    (colour over brightness) and brightness, a robust centre and spread (within
    :data:`HEADSET_SPREAD_FLOOR` and :data:`HEADSET_SPREAD_CAP`). A pixel is the headset's when its
    colour lies within ``tolerance`` spreads of that, within the face's reach (the points' box,
    widened by half its width each side and raised by 60% of its height: :data:`REACH`), in a
    region (opened by a pixel per 96 of the frame, which cuts off strands of hair of its shade)
    that holds a seed. Plastic of any colour (white, grey, black, tinted) is found so. A frame
    where fewer than :data:`HEADSET_MIN_SHARE` of the seeds' pixels are unlike the skin, or whose
    region covers the mouth, has no headset (the eyes are seen): an empty mask. The region found
    so is widened at the end by a pixel per 96 of the frame, at least 2 (a video's colour is
    stored at half resolution): its rim, blurred into the face by the lens and the codec, has
    neither's colour.

    Without ``points`` (or in a frame without them) a headset of a neutral colour is assumed
    (grey or black plastic): a pixel is the headset's when its colour is unsaturated (chroma over
    value, the value counted as at least 0.25 so that sensor noise on dark plastic does not read
    as colour, below ``max_saturation``; skin is 0.25 and more) and not the background (value
    above ``min_value``), in the largest such region.

    Each frame's region is closed by ``close_px`` pixels and its holes filled (the headset is one
    solid piece). A frame without such a region gets an empty mask."""
    from scipy import ndimage

    if not (0 < max_saturation < 1) or not (0 <= min_value < 1) or close_px < 0 or not tolerance > 0:
        raise GeofaceError(f"headset colour: 0 < max_saturation < 1, 0 <= min_value < 1, close_px >= 0, tolerance > 0; "
                           f"got {max_saturation}, {min_value}, {close_px}, {tolerance}")
    pts = None
    if points is not None:
        pts = np.asarray(points, np.float64)
        if pts.ndim != 3 or pts.shape[1:] != (468, 2):
            raise GeofaceError(f"headset masks take the face mesh's points as (T, 468, 2); got shape {pts.shape}")
        from geoface.track import ibug68_from_mediapipe

        idx, w = ibug68_from_mediapipe()
        pts = np.einsum("tkjd,kj->tkd", pts[:, idx], w)  # the 68 iBUG points
    out = []
    for t, img in enumerate(frames):
        a = np.asarray(img)
        if a.ndim != 3 or a.shape[2] < 3:
            raise GeofaceError(f"headset masks need RGB frames; got shape {a.shape}")
        a = a[..., :3].astype(np.float32) / (255.0 if a.dtype == np.uint8 else 1.0)
        if pts is not None and t >= len(pts):
            raise GeofaceError(f"headset masks: {len(pts)} frames of points for more frames")
        P = None if pts is None else pts[t]
        learned = P is not None and bool(np.isfinite(P[list(HEADSET_SEEDS)]).all())
        if learned:
            big = _headset_by_colour(a, P, tolerance)
        else:
            big = _headset_by_greyness(a, max_saturation, min_value)
        if big is None or not big.any():
            out.append(np.zeros(a.shape[:2], bool))
            continue
        if close_px:
            big = ndimage.binary_closing(big, iterations=close_px, border_value=0) | big
        big = ndimage.binary_fill_holes(big)
        if learned:  # its rim, blurred into the face by the lens and the codec, is neither's colour
            big = ndimage.binary_dilation(big, iterations=max(2, min(big.shape) // 96))
        out.append(big)
    return np.stack(out) if out else np.zeros((0, 0, 0), bool)


def _headset_by_greyness(a, max_saturation, min_value):
    """The largest unsaturated region of the frame ``a`` (:func:`headset_masks` without points)."""
    from scipy import ndimage

    value = a.max(-1)
    sat = (value - a.min(-1)) / np.maximum(value, 0.25)
    cand = (sat < max_saturation) & (value > min_value)
    lab, n = ndimage.label(cand)
    if n == 0:
        return None
    return lab == 1 + int(np.argmax(ndimage.sum(cand, lab, range(1, n + 1))))


def _colour_features(a):
    """(chromaticity (..., 3): each channel over the channels' mean, less one; the log of that
    mean, the brightness)."""
    m = a.mean(-1)
    return (a - m[..., None]) / np.maximum(m, 0.1)[..., None], np.log(m + 0.02)


def _samples(a, P, window: int = 1):
    """The frame's pixels ``(k, 3)`` in a ``(2 window + 1)²`` square round each point of ``P``."""
    H, W = a.shape[:2]
    d = np.arange(-window, window + 1)
    cols = np.clip(np.round(P[:, 0] - 0.5)[:, None, None] + d[None, None, :], 0, W - 1).astype(np.int64)
    rows = np.clip(np.round(P[:, 1] - 0.5)[:, None, None] + d[None, :, None], 0, H - 1).astype(np.int64)
    return a[rows, cols].reshape(-1, 3)


def _colour_model(c, b, cap: bool = False, floor=HEADSET_SPREAD_FLOOR):
    """(centre, spreads) of colour features (:func:`_colour_features`): medians, and 1.4826 × the
    median deviation at least ``floor`` (with ``cap``, at most :data:`HEADSET_SPREAD_CAP`)."""
    c0, b0 = np.median(c, 0), float(np.median(b))
    sc = max(1.4826 * float(np.median(np.linalg.norm(c - c0, axis=-1))), floor[0])
    sb = max(1.4826 * float(np.median(np.abs(b - b0))), floor[1])
    if cap:
        sc, sb = min(sc, HEADSET_SPREAD_CAP[0]), min(sb, HEADSET_SPREAD_CAP[1])
    return c0, b0, sc, sb


def _colour_distance(x, model):
    """Each colour of ``x (..., 3)`` from a :func:`_colour_model`, in its spreads."""
    c0, b0, sc, sb = model
    cx, bx = _colour_features(x)
    return np.sqrt((np.linalg.norm(cx - c0, axis=-1) / sc) ** 2 + ((bx - b0) / sb) ** 2)


def _headset_by_colour(a, P, tolerance):
    """The headset's region in the frame ``a`` from the 68 points ``P`` (:func:`headset_masks`), or
    None where the seeds show the skin's colour: the seeds' pixels unlike the skin's (at the
    cheeks and the chin) give the headset's colour; where fewer than :data:`HEADSET_MIN_SHARE` of
    them are, the upper face is seen."""
    from scipy import ndimage

    seeds = P[list(HEADSET_SEEDS)]  # all finite (the caller's test)
    S = _samples(a, seeds)
    least = HEADSET_MIN_SHARE * len(S)
    skin = np.stack([0.5 * (P[i] + P[j]) for i, j in SKIN_SAMPLES])
    skin = skin[np.isfinite(skin).all(1)]
    if len(skin):
        S = S[_colour_distance(S, _colour_model(*_colour_features(_samples(a, skin)), floor=SKIN_SPREAD_FLOOR)) >= tolerance]
    if len(S) < least:
        return None
    model = _colour_model(*_colour_features(S), cap=True)
    for _ in range(2):  # again from the pixels of that colour (the seeds on hair or eyes left out)
        near = S[_colour_distance(S, model) < tolerance]
        if len(near) < least:
            break
        model = _colour_model(*_colour_features(near), cap=True)
    H, W = a.shape[:2]
    ok = np.isfinite(P).all(1)
    lo, hi = P[ok].min(0), P[ok].max(0)
    w, h = hi - lo
    x0, x1 = int(np.floor(lo[0] - REACH[0] * w)), int(np.ceil(hi[0] + REACH[0] * w))
    y0, y1 = int(np.floor(lo[1] - REACH[1] * h)), int(np.ceil(hi[1]))
    reach = np.zeros((H, W), bool)
    reach[max(y0, 0):max(min(y1, H), 0), max(x0, 0):max(min(x1, W), 0)] = True
    cand = (_colour_distance(a, model) < tolerance) & reach
    # opened by a pixel per 96 of the frame: a strand of hair of the headset's shade that touches
    # it is cut off
    cand = ndimage.binary_opening(cand, iterations=max(1, min(H, W) // 96))
    lab, _ = ndimage.label(cand)
    r = np.clip(np.floor(seeds[:, 1]).astype(np.int64), 0, H - 1)
    q = np.clip(np.floor(seeds[:, 0]).astype(np.int64), 0, W - 1)
    keep = np.setdiff1d(np.unique(lab[r, q]), [0])
    if not len(keep):
        return None
    region = np.isin(lab, keep)
    mouth = P[60:68][np.isfinite(P[60:68]).all(1)]
    mi = np.clip(np.floor(mouth).astype(np.int64), 0, [W - 1, H - 1])
    if region[mi[:, 1], mi[:, 0]].any():  # a headset never covers the mouth: this is the face
        return None
    return region
