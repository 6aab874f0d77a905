"""Rotations in numpy, one module for the whole library: axis-angle (Rodrigues) both ways, yaw /
pitch / roll, quaternions from matrices, the look-at rotation of a camera and the upright frame of a head. Matrices are
(3, 3) float64, proper (det +1), acting on column vectors (``X' = R @ X``). The differentiable
torch twins live beside the code that trains through them: ``geoface.avatar.kinematics.
axis_angle_to_matrix`` and the quaternion functions of ``geoface.splat.gaussians``.

>>> import numpy as np
>>> R = rodrigues([0.0, 0.0, np.pi / 2])            # a quarter turn about +z
>>> (R @ [1.0, 0.0, 0.0]).round(6).tolist()
[0.0, 1.0, 0.0]
>>> rotation_vector(R).round(6).tolist()
[0.0, 0.0, 1.570796]
"""

from __future__ import annotations

import math

import numpy as np

from .errors import CameraError

__all__ = ["rodrigues", "rotation_vector", "euler_rotation", "rotmat_to_quat", "look_at_rotation", "upright_rotation"]


def rodrigues(w) -> np.ndarray:
    """Rotation matrix of the axis-angle vector ``w`` (radians)."""
    w = np.asarray(w, np.float64)
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3)
    k = w / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def rodrigues_axes(w) -> np.ndarray:
    """(3, 3): row ``i`` is the axis ``a_i`` with ∂(R(w) q)/∂w_i = a_i × (R(w) q) for every ``q``
    (:func:`rodrigues`'s derivative, Gallego & Yezzi 2015:
    a_i = (w_i w + w × (I − R) e_i) / |w|²; the unit axes at w = 0)."""
    w = np.asarray(w, np.float64)
    n2 = float(w @ w)
    if n2 < 1e-24:
        return np.eye(3)
    IR = np.eye(3) - rodrigues(w)
    return (w[:, None] * w[None, :] + np.cross(w[None, :], IR.T)) / n2


def rotation_vector(R) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (inverse of :func:`rodrigues`)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, np.float64)).as_rotvec()


def euler_rotation(yaw, pitch, roll) -> np.ndarray:
    """``Ry(yaw) @ Rx(pitch) @ Rz(roll)`` (radians; y up): a head turning, nodding, tilting."""
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch),
                              math.cos(roll), math.sin(roll))
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:  # [N, 3, 3] -> [N, 4] (w, x, y, z), w >= 0
    """Quaternions from proper rotation matrices (Shepperd's method, numerically robust)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R, axis1=1, axis2=2)
    cand = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    k = np.argmax(cand, 1)
    q = np.empty((len(R), 4))
    for i in range(4):  # four branches, each vectorised over its rows
        m = k == i
        r = R[m]
        if i == 0:
            s = np.sqrt(1 + tr[m]) * 2
            q[m] = np.stack([s / 4, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                             (r[:, 1, 0] - r[:, 0, 1]) / s], 1)
        else:
            a, b, c = i - 1, i % 3, (i + 1) % 3
            s = np.sqrt(1 + r[:, a, a] - r[:, b, b] - r[:, c, c]) * 2
            v = np.empty((m.sum(), 4))
            v[:, 0] = (r[:, c, b] - r[:, b, c]) / s
            v[:, 1 + a] = s / 4
            v[:, 1 + b] = (r[:, b, a] + r[:, a, b]) / s
            v[:, 1 + c] = (r[:, c, a] + r[:, a, c]) / s
            q[m] = v
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def look_at_rotation(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World → camera rotation for a camera at ``eye`` looking at ``target``.

    The camera +z axis points from ``eye`` to ``target``; the image +y (down) axis is opposite
    to ``up`` projected onto the image plane, so ``up`` appears at the top of the image.
    """
    eye, target, up = (np.asarray(a, dtype=np.float64).reshape(3) for a in (eye, target, up))
    z = target - eye
    nz = np.linalg.norm(z)
    if nz < 1e-12:
        raise CameraError("look_at: eye and target coincide")
    z = z / nz
    x = np.cross(-up, z)  # right = down × forward (x = y × z)
    nx = np.linalg.norm(x)
    if nx < 1e-9:
        raise CameraError("look_at: up is parallel to the viewing direction")
    x = x / nx
    y = np.cross(z, x)
    return np.stack([x, y, z])  # rows are camera axes in world coordinates


def upright_rotation(up, front) -> np.ndarray:
    """The rotation whose rows are (right, up, front) — ``right = up × front`` — of a head: it
    takes the input's coordinates to upright ones (x right, y up, z front), so that the same head
    in any axis convention is stored as the same pixels.  ``front`` is made orthogonal to ``up``
    (+Z or +X when it is parallel)."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    f = np.asarray(front, np.float64) - (np.asarray(front, np.float64) @ u) * u
    if np.linalg.norm(f) < 1e-9:
        f = np.array([0.0, 0.0, 1.0]) - u[2] * u
        if np.linalg.norm(f) < 1e-9:
            f = np.array([1.0, 0.0, 0.0]) - u[0] * u
    f = f / np.linalg.norm(f)
    return np.stack([np.cross(u, f), u, f])
