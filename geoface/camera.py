"""Pinhole cameras in the OpenCV convention (+x right, +y down, +z forward).

A :class:`Camera` maps a world point ``X`` to camera coordinates ``Xc = R @ X + t`` and to
pixels ``u = fx * Xc.x / Xc.z + cx``, ``v = fy * Xc.y / Xc.z + cy``. Pixel ``(i, j)`` (row,
column) has its centre at ``(u, v) = (j + 0.5, i + 0.5)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoface.errors import CameraError
from geoface.rotations import look_at_rotation  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera. ``R`` (3, 3) and ``t`` (3,) map world → camera coordinates."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    R: np.ndarray  # [3, 3] float64, world → camera rotation
    t: np.ndarray  # [3] float64

    def __post_init__(self):
        R = np.asarray(self.R, dtype=np.float64)
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        if R.shape != (3, 3):
            raise CameraError(f"R must have shape (3, 3); got {R.shape}")
        if t.shape != (3,):
            raise CameraError(f"t must have shape (3,); got {t.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise CameraError("R must be a proper rotation matrix (orthonormal, det +1)")
        if not (self.fx > 0 and self.fy > 0):
            raise CameraError(f"focal lengths must be positive; got fx={self.fx}, fy={self.fy}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise CameraError(f"image size must be positive; got {self.width}x{self.height}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def from_fov(cls, fov_y_deg: float, width: int, height: int, R, t) -> "Camera":
        """Square-pixel camera with vertical field of view ``fov_y_deg`` and centred principal point."""
        if not 0 < fov_y_deg < 180:
            raise CameraError(f"fov_y_deg must lie in (0, 180); got {fov_y_deg}")
        f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2)
        return cls(f, f, width / 2, height / 2, width, height, R, t)

    @classmethod
    def from_K(cls, K, R, t, width: int | None = None, height: int | None = None) -> "Camera":
        """From an intrinsic matrix ``K (3, 3)`` (OpenCV: Xc = R X + t, +z forward, y down); the image
        size defaults to twice the principal point."""
        K = np.asarray(K, np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise CameraError(f"camera K must be a finite (3, 3) array; got {K.shape}")
        if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]) or np.abs(K[2] - [0, 0, 1]).max() > 1e-9:
            raise CameraError("camera K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        w = int(round(2 * cx)) if width is None else int(width)
        h = int(round(2 * cy)) if height is None else int(height)
        return cls(fx, fy, cx, cy, max(w, 1), max(h, 1), R, t)

    @classmethod
    def from_matrix(cls, K, Rt, width: int | None = None, height: int | None = None) -> "Camera":
        """From ``K`` and a 4×4 (or 3×4) world→camera matrix."""
        Rt = np.asarray(Rt, np.float64)
        if Rt.shape not in ((4, 4), (3, 4)):
            raise CameraError(f"extrinsics must be a 3x4 or 4x4 matrix; got {Rt.shape}")
        return cls.from_K(K, Rt[:3, :3], Rt[:3, 3], width, height)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix, (3, 3) float64."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,)."""
        return -self.R.T @ self.t

    def world_to_camera(self, X):
        """World points (n, 3) → camera coordinates (n, 3). Works on numpy arrays and torch tensors."""
        if isinstance(X, np.ndarray):
            return X @ self.R.T + self.t
        import torch
        R = torch.as_tensor(self.R, dtype=X.dtype, device=X.device)
        t = torch.as_tensor(self.t, dtype=X.dtype, device=X.device)
        return X @ R.T + t

    def project(self, X):
        """World points (n, 3) → (uv (n, 2) pixels, depth (n,)). Depth is camera-space z."""
        Xc = self.world_to_camera(X)
        z = Xc[:, 2]
        zs = np.where(np.abs(z) > 1e-12, z, 1e-12) if isinstance(X, np.ndarray) else z
        u = self.fx * Xc[:, 0] / zs + self.cx
        v = self.fy * Xc[:, 1] / zs + self.cy
        stack = np.stack if isinstance(X, np.ndarray) else __import__("torch").stack
        return stack([u, v], 1), z


def look_at(eye, target, up=(0.0, 1.0, 0.0), *, width=256, height=256, fov_y_deg=40.0) -> Camera:
    """Camera at ``eye`` looking at ``target`` with ``up`` at the top of the image.

    Examples
    --------
    >>> cam = look_at([0, 0, 3], [0, 0, 0])
    >>> cam.project(np.zeros((1, 3)))[0]
    array([[128., 128.]])
    """
    R = look_at_rotation(eye, target, up)
    t = -R @ np.asarray(eye, dtype=np.float64).reshape(3)
    return Camera.from_fov(fov_y_deg, width, height, R, t)


def orbit(n: int, radius: float, elevation: float = 0.0, *, target=(0.0, 0.0, 0.0),
          up=(0.0, 1.0, 0.0), start_azimuth: float = 0.0, width=256, height=256,
          fov_y_deg=40.0) -> list[Camera]:
    """``n`` cameras evenly spaced in azimuth on a circle around ``target`` (y up).

    ``elevation`` (degrees) lifts the circle above the target's horizontal plane; azimuth 0
    puts the camera on +z looking towards −z. Every camera sits at distance ``radius``.
    """
    if n < 1:
        raise CameraError(f"orbit: n must be >= 1; got {n}")
    if radius <= 0:
        raise CameraError(f"orbit: radius must be positive; got {radius}")
    target = np.asarray(target, dtype=np.float64).reshape(3)
    el = np.radians(elevation)
    cams = []
    for k in range(n):
        az = np.radians(start_azimuth) + 2 * np.pi * k / n
        offset = radius * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
        cams.append(look_at(target + offset, target, up, width=width, height=height,
                            fov_y_deg=fov_y_deg))
    return cams
