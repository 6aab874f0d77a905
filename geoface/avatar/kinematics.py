"""Kinematic chains in torch: axis-angle rotations (Rodrigues, smooth at zero) and the per-joint
transforms G_j(θ) · G_j(0)⁻¹ of forward kinematics (THGS eq. 4–5) and the linear blend skinning of
points by them, shared by the THGS model
(:mod:`geoface.thgs.model`) and its data generator (:mod:`geoface.thgs.data`)."""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["axis_angle_to_matrix", "joint_transforms", "skin_points"]


def axis_angle_to_matrix(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3] (Rodrigues, smooth at 0)
    th2 = (w * w).sum(-1, keepdim=True)[..., None]
    K = torch.zeros(w.shape[:-1] + (3, 3), dtype=w.dtype, device=w.device)
    x, y, z = w.unbind(-1)
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 0] = -z, y, z
    K[..., 1, 2], K[..., 2, 0], K[..., 2, 1] = -x, -y, x
    small = th2 < 1e-8
    safe = torch.where(small, torch.ones_like(th2), th2)  # no 0/0 in the unused branch's gradient
    th = torch.sqrt(safe)
    a = torch.where(small, 1 - th2 / 6, torch.sin(th) / th)
    b = torch.where(small, 0.5 - th2 / 24, (1 - torch.cos(th)) / safe)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(K.shape)
    return eye + a * K + b * (K @ K)


def joint_transforms(joints: Tensor, parents, rot: Tensor, transl: Tensor | None = None) -> Tensor:
    """[..., J, 4, 4] transforms A_j mapping rest-pose points bound to joint j to the posed ones.

    ``joints`` [J, 3] rest positions, ``parents`` (J,) (−1 root, parents first), ``rot`` [..., J, 3]
    local axis-angle rotations about each joint, ``transl`` [..., 3] root translation; leading
    dimensions (frames) are a batch."""
    J = len(joints)
    R = axis_angle_to_matrix(rot)  # [..., J, 3, 3]
    batch = rot.shape[:-2]
    G = []
    for j in range(J):
        p = int(parents[j])
        t = joints[j] - (joints[p] if p >= 0 else 0.0)
        L = torch.zeros(batch + (4, 4), dtype=joints.dtype, device=joints.device)
        L[..., :3, :3] = R[..., j, :, :]
        L[..., :3, 3] = t
        L[..., 3, 3] = 1.0
        G.append(L if p < 0 else G[p] @ L)
    G = torch.stack(G, -3)
    if transl is not None:
        G = G.clone()
        G[..., :3, 3] = G[..., :3, 3] + transl[..., None, :]
    # A_j = G_j · G_j(0)⁻¹ with G_j(0) a pure translation by the rest joint position
    A = G.clone()
    A[..., :3, 3] = G[..., :3, 3] - (G[..., :3, :3] @ joints[..., None])[..., 0]
    return A


def skin_points(X: Tensor, W: Tensor, A: Tensor) -> Tensor:
    """x' = Σ w_j A_j x: points X [..., N, 3] with weights W [N, J] under joint transforms
    A [..., J, 4, 4] (leading dimensions: a batch of frames)."""
    M = torch.einsum("nj,...jab->...nab", W, A)  # [..., N, 4, 4]
    return (M[..., :3, :3] @ X[..., None])[..., 0] + M[..., :3, 3]
