"""Facial regions of the ICT-FaceKit UV layout, for skin whose statistics depend on where it is.

:func:`ict_uv_regions` draws soft masks ``[R, R]`` in ``[0, 1]`` over the model's face tile (UV
``[0, 1]²``; row 0 is v = 1, as geoface textures) from the 68 landmarks of a head, mapped to UV
through the layout (the layout is shared by every identity and expression, so the regions are
too, up to the landmarks' small UV drift):

* ``face`` — the model's face area (its face mask) rasterised;
* ``lips`` — the outer lip contour (landmarks 48–59) less the mouth opening (60–67);
* ``brows`` — a band around each brow's polyline (17–21, 22–26);
* ``eyelids`` — a ring around each eye contour (36–41, 42–47), the opening excluded;
* ``nose`` — the hull of the bridge and nostrils (27–35), widened;
* ``cheeks`` — a disc on each side between the lower eyelid and the mouth corner;
* ``forehead`` — the face above the brows;
* ``beard`` — the lower face inside the jaw line (2–14) below the nose, lips excluded.

Sizes are fractions of the face's own landmark distances (eye width, brow-to-chin), so the
masks follow the layout, not the resolution; edges are softened by a Gaussian of 0.4 % of the
tile.  :func:`geoface.texture.synth.skin_maps` takes these masks (``regions=``) and varies
pores, colour, hair, lines and shine by region.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from . import SkinError

__all__ = ["REGION_NAMES", "ict_uv_regions", "landmark_uv"]

REGION_NAMES = ("face", "lips", "brows", "eyelids", "nose", "cheeks", "forehead", "beard")
SOFT = 0.004  # UV units: the Gaussian that softens every mask's edge


def landmark_uv(head) -> np.ndarray:
    """``(68, 2)`` UV coordinates of an :class:`geoface.synth.ict.ICTHead`'s landmarks (from any
    face corner at the landmark vertex)."""
    vuv = np.full((len(head.V), 2), np.nan)
    vuv[np.asarray(head.F).ravel()] = np.asarray(head.UV)[np.asarray(head.FUV).ravel()]
    lm = np.asarray(head.landmarks)
    if (lm < 0).any():
        raise SkinError("the head lacks some of the 68 landmarks (build it with the face parts)")
    out = vuv[lm]
    if not np.isfinite(out).all():
        raise SkinError("a landmark vertex has no texture coordinate")
    return out


def _grid(R: int) -> tuple[np.ndarray, np.ndarray]:
    """UV of each pixel centre (u right, v up, row 0 = v 1)."""
    c = (np.arange(R) + 0.5) / R
    return np.meshgrid(c, 1.0 - c)


def _polygon(R: int, pts: np.ndarray) -> np.ndarray:
    from skimage.draw import polygon
    img = np.zeros((R, R), np.float64)
    rr, cc = polygon((1.0 - pts[:, 1]) * R - 0.5, pts[:, 0] * R - 0.5, shape=(R, R))
    img[rr, cc] = 1.0
    return img


def _dist_to_polyline(u, v, pts: np.ndarray, closed: bool = False) -> np.ndarray:
    P = np.stack([u, v], -1)
    seg = list(zip(pts[:-1], pts[1:])) + ([(pts[-1], pts[0])] if closed else [])
    d = np.full(u.shape, np.inf)
    for a, b in seg:
        ab = b - a
        t = np.clip(((P - a) @ ab) / max(float(ab @ ab), 1e-18), 0, 1)
        d = np.minimum(d, np.linalg.norm(P - (a + t[..., None] * ab), axis=-1))
    return d


def _hull(pts: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull
    return pts[ConvexHull(pts).vertices]


def _soft(img: np.ndarray, R: int) -> np.ndarray:
    return np.clip(ndimage.gaussian_filter(img.astype(np.float64), SOFT * R), 0, 1)


def ict_uv_regions(res: int = 512, head=None, *, model=None) -> dict[str, np.ndarray]:
    """Soft region masks ``{name: [res, res] float32}`` (:data:`REGION_NAMES`) of the ICT layout.

    ``head``: an :class:`geoface.synth.ict.ICTHead` (default: the model's mean head, from
    ``model`` or the installed ICT-FaceKit model)."""
    from geoface.gimage.raster import rasterize_faces
    if not 16 <= int(res) <= 8192:
        raise SkinError(f"res must be in 16..8192; got {res}")
    if head is None:
        from geoface.synth.ict import load_ict_model
        model = model or load_ict_model()
        head = model.head(identity=np.zeros(model.n_identities))
    R = int(res)
    L = landmark_uv(head)
    if not ((L >= 0) & (L <= 1)).all():
        raise SkinError("the landmarks are not in the face tile UV [0, 1]² (not the ICT layout?)")
    u, v = _grid(R)
    eye_w = 0.5 * (np.linalg.norm(L[39] - L[36]) + np.linalg.norm(L[45] - L[42]))
    face_h = float(L[19:25, 1].max() - L[8, 1])  # brow to chin
    # face: the face-mask triangles that lie in the tile
    F, FUV, UV = np.asarray(head.F), np.asarray(head.FUV), np.asarray(head.UV)
    keep = np.asarray(head.face_mask, bool)[F].all(1) & ((UV[FUV] >= 0) & (UV[FUV] <= 1)).all(axis=(1, 2))
    face_idx, _ = rasterize_faces(FUV[keep], UV, R)
    face = (face_idx >= 0).astype(np.float64)
    face = ndimage.binary_closing(face, iterations=2).astype(np.float64)

    lips = np.clip(_polygon(R, L[48:60]) - _polygon(R, L[60:68]), 0, 1)
    lips = np.maximum(lips, (_dist_to_polyline(u, v, L[48:60], closed=True) < 0.05 * eye_w) * 1.0)
    brows = np.zeros((R, R))
    for idx in (slice(17, 22), slice(22, 27)):
        brows = np.maximum(brows, (_dist_to_polyline(u, v, L[idx]) < 0.16 * eye_w) * 1.0)
    lids = np.zeros((R, R))
    for idx in (slice(36, 42), slice(42, 48)):
        ring = _dist_to_polyline(u, v, L[idx], closed=True) < 0.35 * eye_w
        lids = np.maximum(lids, ring * (1 - _polygon(R, L[idx])))
    nose_pts = L[27:36]
    c = nose_pts.mean(0)
    nose = _polygon(R, _hull(c + 1.25 * (nose_pts - c)))
    cheeks = np.zeros((R, R))
    for eye, corner, out in ((slice(36, 42), 48, -1.0), (slice(42, 48), 54, 1.0)):
        centre = 0.5 * (L[eye].mean(0) + L[corner]) + np.array([out * 0.35 * eye_w, 0.0])
        r = 0.45 * np.linalg.norm(L[eye].mean(0) - L[corner])
        cheeks = np.maximum(cheeks, np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2 * (0.6 * r) ** 2)))
    brow_top = float(L[17:27, 1].max())
    forehead = np.clip((v - brow_top - 0.03 * face_h) / (0.08 * face_h), 0, 1)
    forehead *= (np.abs(u - L[27, 0]) < 0.6 * (L[16, 0] - L[0, 0])) * 1.0
    jaw = np.vstack([L[2:15], L[35][None] + [0.0, 0.02 * face_h], L[31][None] + [0.0, 0.02 * face_h]])
    beard = _polygon(R, jaw) * (v < L[33, 1]) * (1 - ndimage.binary_dilation(lips > 0.5, iterations=max(1, R // 256)))
    out = {"face": face, "lips": lips, "brows": brows, "eyelids": lids, "nose": nose, "cheeks": cheeks,
           "forehead": forehead, "beard": beard}
    return {k: (_soft(m, R) * (_soft(face, R) if k != "face" else 1.0)).astype(np.float32) for k, m in out.items()}
