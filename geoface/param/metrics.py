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
>>> distortion(V, F, V[:, :2]).summary()["qc_max"]
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
        if not ok.any():
            inf = float("inf")
            return {"qc_mean": inf, "qc_area_weighted": inf, "qc_p95": inf, "qc_max": inf, "log_area_abs_mean": inf,
                    "log_area_abs_p95": inf, "area_ratio_max": inf, "flipped": int(self.flipped.sum()), "degenerate": int(deg.sum())}
        qc = self.qc[ok] if ok.any() else np.array([np.inf])
        la = np.abs(self.log_area[ok]) if ok.any() else np.array([np.inf])
        w = self.area_3d[ok] / max(self.area_3d[ok].sum(), 1e-300) if ok.any() else np.array([1.0])
        return {
            "qc_mean": float(qc.mean()),
            "qc_area_weighted": float((qc * w).sum()),
            "qc_p95": float(np.quantile(qc, 0.95)),
            "qc_max": float(qc.max()),
            "log_area_abs_mean": float(la.mean()),
            "log_area_abs_p95": float(np.quantile(la, 0.95)),
            "area_ratio_max": float(np.exp(la.max())),
            "flipped": int(self.flipped.sum()),
            "degenerate": int(deg.sum()),
        }


def distortion(V, F, UV) -> Distortion:
    """Distortion of the map ``V -> UV`` on every triangle of ``F``."""
    V, F = check_mesh(V, F)
    UV = np.asarray(UV, np.float64)
    if UV.shape != (len(V), 2):
        raise InvalidMeshError(f"UV must have shape ({len(V)}, 2); got {UV.shape}")
    P = V[F]
    e1 = P[:, 1] - P[:, 0]
    e2 = P[:, 2] - P[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    x = e1 / np.maximum(l1, 1e-300)[:, None]
    e2x = (e2 * x).sum(1)
    y = e2 - e2x[:, None] * x
    e2y = np.linalg.norm(y, axis=1)
    # local 2D frame of the 3D triangle: columns (l1, 0) and (e2x, e2y)
    Q = UV[F]
    q1 = Q[:, 1] - Q[:, 0]
    q2 = Q[:, 2] - Q[:, 0]
    # J = [q1 q2] @ inv([[l1, e2x], [0, e2y]])
    inv00 = 1.0 / np.maximum(l1, 1e-300)
    inv11 = 1.0 / np.maximum(e2y, 1e-300)
    inv01 = -e2x * inv00 * inv11
    J = np.empty((len(F), 2, 2))
    J[:, :, 0] = q1 * inv00[:, None]
    J[:, :, 1] = q1 * inv01[:, None] + q2 * inv11[:, None]
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
