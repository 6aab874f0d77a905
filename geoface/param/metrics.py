"""Distortion of a parameterization: quasi-conformal ratio, area ratio, flipped triangles.

For each triangle, ``J`` is the 2x2 Jacobian of the affine map from the 3D triangle (in
its own plane) to its UV triangle; with singular values ``s1 >= s2``:

* quasi-conformal ratio ``qc = s1 / s2`` (1 = conformal, angles preserved);
* log area ratio ``log((A_uv / sum A_uv) / (A_3d / sum A_3d))`` (0 = area preserving);
* flipped: ``det J < 0`` (the UV triangle is reversed);
* degenerate: UV area at most 1e-9 of the mean UV triangle area (a sliver).

Summaries leave flipped and degenerate triangles out of the QC and area statistics and
count them separately.

>>> from geoface.synth import square_grid
>>> V, F = square_grid(4)
>>> round(distortion(V, F, V[:, :2]).summary()["qc_max"], 9)
1.0
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidMeshError
from ..mesh.core import check_mesh


@dataclass(frozen=True)
class Distortion:
    """Per-triangle distortion arrays (see module docs) and their summary."""

    qc: np.ndarray
    log_area: np.ndarray
    flipped: np.ndarray
    area_3d: np.ndarray
    degenerate: np.ndarray | None = None

    def summary(self) -> dict:
        deg = np.zeros_like(self.flipped) if self.degenerate is None else self.degenerate
        ok = ~self.flipped & ~deg & np.isfinite(self.qc)
        return {**_summary_stats(self.qc, self.log_area, self.area_3d, ok), "flipped": int(self.flipped.sum()),
                "degenerate": int(deg.sum())}


def _summary_stats(qc: np.ndarray, log_area: np.ndarray, area_3d: np.ndarray, ok: np.ndarray) -> dict:
    """QC and area statistics over the faces ``ok`` (all infinite when there are none)."""
    keys = ("qc_mean", "qc_area_weighted", "qc_p95", "qc_max", "log_area_abs_mean", "log_area_abs_p95", "area_ratio_max")
    if not ok.any():
        return dict.fromkeys(keys, float("inf"))
    qc, la = qc[ok], np.abs(log_area[ok])
    w = area_3d[ok] / max(area_3d[ok].sum(), 1e-300)
    vals = (qc.mean(), (qc * w).sum(), np.quantile(qc, 0.95), qc.max(), la.mean(), np.quantile(la, 0.95), np.exp(la.max()))
    return {k: float(v) for k, v in zip(keys, vals)}


def _face_frames(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each 3D triangle in its own plane: ``(l1, e2x, e2y)``, its edge 0→1 being ``(l1, 0)`` and
    its edge 0→2 ``(e2x, e2y)``."""
    P = V[F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    x = e1 / np.maximum(l1, 1e-300)[:, None]
    e2x = (e2 * x).sum(1)
    return l1, e2x, np.linalg.norm(e2 - e2x[:, None] * x, axis=1)


def _jacobians(q1, q2, l1, e2x, e2y) -> np.ndarray:
    """[n, 2, 2] Jacobians ``[q1 q2] @ inv([[l1, e2x], [0, e2y]])``: the UV edges ``q1``, ``q2`` [n, 2]
    of triangles whose own 2D frame is :func:`_face_frames`'."""
    inv00 = 1.0 / np.maximum(l1, 1e-300)
    inv11 = 1.0 / np.maximum(e2y, 1e-300)
    inv01 = -e2x * inv00 * inv11
    J = np.empty((len(q1), 2, 2))
    J[:, :, 0] = q1 * inv00[:, None]
    J[:, :, 1] = q1 * inv01[:, None] + q2 * inv11[:, None]
    return J


def distortion(V, F, UV) -> Distortion:
    """Distortion of the map ``V -> UV`` on every triangle of ``F``."""
    V, F = check_mesh(V, F)
    UV = np.asarray(UV, np.float64)
    if UV.shape != (len(V), 2):
        raise InvalidMeshError(f"UV must have shape ({len(V)}, 2); got {UV.shape}")
    l1, e2x, e2y = _face_frames(V, F)
    Q = UV[F]
    q1 = Q[:, 1] - Q[:, 0]
    q2 = Q[:, 2] - Q[:, 0]
    J = _jacobians(q1, q2, l1, e2x, e2y)
    s = np.linalg.svd(J, compute_uv=False)
    det = np.linalg.det(J)
    with np.errstate(divide="ignore", invalid="ignore"):
        qc = np.where(s[:, 1] > 0, s[:, 0] / s[:, 1], np.inf)
    a3 = 0.5 * l1 * e2y
    auv = 0.5 * np.abs(q1[:, 0] * q2[:, 1] - q1[:, 1] * q2[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        log_area = np.log((auv / auv.sum()) / (a3 / a3.sum()))
    sliver = auv <= 1e-9 * max(float(auv.mean()), 1e-300)
    return Distortion(qc=qc, log_area=log_area, flipped=(det < 0) | ((det == 0) & ~sliver), area_3d=a3, degenerate=sliver & (det >= 0))


def _sample_barycentrics(level: int) -> np.ndarray:
    """Centroids ``(level^2, 3)`` of the sub-triangles of a ``level``-times subdivided triangle."""
    pts = []
    for i in range(level):
        for j in range(level - i):
            pts.append((3 * level - 3 * i - 3 * j - 2, 3 * i + 1, 3 * j + 1))  # upward
            if i + j < level - 1:
                pts.append((3 * level - 3 * i - 3 * j - 4, 3 * i + 2, 3 * j + 2))  # downward
    return np.array(pts, np.float64) / (3 * level)


@dataclass(frozen=True)
class MapDistortion:
    """Distortion of a (possibly non-linear) map, from its Jacobian at ``level^2`` points per face.

    ``qc`` (m,) is the mean quasi-conformal ratio over each input face's sample points,
    ``flipped`` (m,) counts its sample points where the map reverses orientation, and
    ``log_area`` (m,) is the log ratio of the face's mapped area (mean Jacobian determinant
    times its area) to its 3D area, both normalised by their totals.  For a map that is
    linear on every face this equals :func:`distortion`.
    """

    qc: np.ndarray
    flipped: np.ndarray
    log_area: np.ndarray
    area_3d: np.ndarray
    level: int

    def summary(self) -> dict:
        ok = (self.flipped == 0) & np.isfinite(self.qc) & np.isfinite(self.log_area)
        return {**_summary_stats(self.qc, self.log_area, self.area_3d, ok), "flipped": int((self.flipped > 0).sum()),
                "flipped_samples": int(self.flipped.sum()), "level": self.level}


def map_distortion(V, F, mapping, level: int = 4, eps: float = 1e-6) -> MapDistortion:
    """Distortion of ``mapping(face, bary) -> (k, 2)`` on the faces ``F`` of the surface ``V``.

    For maps that are not linear on the input triangles, such as a Ricci-flow result with
    intrinsic flips (:meth:`geoface.param.ricci.RicciFlowResult.map_points`, projective on
    the pieces of a common refinement).  The Jacobian is taken by finite differences
    (barycentric step ``eps``) at the centroids of the ``level^2`` sub-triangles of every
    face; sampling the map's values on sub-triangles instead would report folds wherever a
    coarse sub-triangle straddles a bend between pieces.

    >>> from geoface.synth import square_grid
    >>> V, F = square_grid(3)
    >>> map_distortion(V, F, linear_map(F, V[:, :2])).summary()["qc_max"] < 1 + 1e-6
    True
    """
    V, F = check_mesh(V, F)
    if level < 1:
        raise InvalidMeshError(f"level must be >= 1; got {level}")
    B = _sample_barycentrics(int(level))
    m, p = len(F), len(B)
    face = np.repeat(np.arange(m), p)
    b0 = np.tile(B, (m, 1))
    d1 = np.array([-eps, eps, 0.0])
    d2 = np.array([-eps, 0.0, eps])
    uv = np.asarray(mapping(np.tile(face, 3), np.concatenate([b0, b0 + d1, b0 + d2])), np.float64)
    if uv.shape != (3 * len(face), 2):
        raise InvalidMeshError(f"mapping must return shape ({3 * len(face)}, 2); got {uv.shape}")
    u0, u1, u2 = uv[: len(face)], uv[len(face) : 2 * len(face)], uv[2 * len(face) :]
    l1, e2x, e2y = _face_frames(V, F)
    # d(uv)/d(b1), d(uv)/d(b2) at each sample point, against its face's own 2D frame
    J = _jacobians((u1 - u0) / eps, (u2 - u0) / eps, *(np.repeat(a, p) for a in (l1, e2x, e2y)))
    s = np.linalg.svd(J, compute_uv=False)
    det = np.linalg.det(J)
    with np.errstate(divide="ignore", invalid="ignore"):
        qc = np.where(s[:, 1] > 0, s[:, 0] / s[:, 1], np.inf).reshape(m, p)
    flipped = (det <= 0).reshape(m, p)
    a3 = 0.5 * l1 * e2y
    auv = np.abs(det).reshape(m, p).mean(1) * a3
    with np.errstate(divide="ignore", invalid="ignore"):
        log_area = np.log((auv / auv.sum()) / (a3 / a3.sum()))
        qcf = np.where(flipped, np.nan, qc)
        qcf = np.nanmean(np.where(flipped.all(1, keepdims=True), np.inf, qcf), 1)
    return MapDistortion(qc=qcf, flipped=flipped.sum(1), log_area=log_area, area_3d=a3, level=int(level))


def linear_map(F, UV):
    """``mapping(face, bary)`` of the map that is linear on each face of ``F`` with vertex ``UV``."""
    F = np.asarray(F, np.int64)
    UV = np.asarray(UV, np.float64)
    return lambda face, bary: np.einsum("ki,kij->kj", bary, UV[F[face]])
