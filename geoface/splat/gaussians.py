"""3D Gaussians: parameters, covariances, spherical harmonics, init from meshes/points, 3DGS PLY.

Pure functions (``quat_to_rotmat``, ``covariance``, ``eval_sh``) sit under the
:class:`Gaussians` module that owns the parameters.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from geoface.splat.errors import SplatError
from geoface.rotations import rotmat_to_quat  # noqa: F401  (re-exported)

# standard 3DGS real spherical-harmonics constants (degrees 0..3)
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [N, 4] (w, x, y, z), any norm -> [N, 3, 3]
    """Rotation matrices from quaternions (normalised here), scalar first."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of [N, 4] (w, x, y, z) quaternions."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def rotmat_to_quat_torch(R: Tensor) -> Tensor:  # [N, 3, 3] proper rotations -> [N, 4] (w, x, y, z)
    """Quaternions from rotation matrices, differentiable everywhere (Shepperd's method).

    Each row uses the branch with the largest of (trace, R00, R11, R22), whose square root
    is at least 1; the sign-copying formula with clamped square roots has no gradient for
    the vector part at the identity (the rest pose of every joint)."""
    r00, r11, r22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    tr = r00 + r11 + r22
    d21, d02, d10 = R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]
    s01, s02, s12 = R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]
    # every branch with its own (clamped) scale; only the selected one is used
    s0 = 2 * torch.sqrt(torch.clamp(1 + tr, min=1e-12))
    s1 = 2 * torch.sqrt(torch.clamp(1 + r00 - r11 - r22, min=1e-12))
    s2 = 2 * torch.sqrt(torch.clamp(1 - r00 + r11 - r22, min=1e-12))
    s3 = 2 * torch.sqrt(torch.clamp(1 - r00 - r11 + r22, min=1e-12))
    cand = torch.stack([
        torch.stack([s0 / 4, d21 / s0, d02 / s0, d10 / s0], -1),
        torch.stack([d21 / s1, s1 / 4, s01 / s1, s02 / s1], -1),
        torch.stack([d02 / s2, s01 / s2, s2 / 4, s12 / s2], -1),
        torch.stack([d10 / s3, s02 / s3, s12 / s3, s3 / 4], -1),
    ], 1)  # [N, 4 branches, 4]
    k = torch.argmax(torch.stack([tr, r00, r11, r22], -1), -1)
    q = torch.gather(cand, 1, k[:, None, None].expand(-1, 1, 4))[:, 0]
    q = q * torch.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0
    return q / q.norm(dim=-1, keepdim=True)


def covariance(log_scales: Tensor, quats: Tensor) -> Tensor:  # [N,3], [N,4] -> [N,3,3]
    """Σ = R S Sᵀ Rᵀ with S = diag(exp(log_scales))."""
    M = quat_to_rotmat(quats) * torch.exp(log_scales)[..., None, :]  # R S
    return M @ M.transpose(-1, -2)


def sh_degree_from_k(k: int) -> int:
    d = int(round(np.sqrt(k))) - 1
    if (d + 1) ** 2 != k or not 0 <= d <= 3:
        raise SplatError(f"SH coefficient count must be 1, 4, 9 or 16; got {k}")
    return d


def eval_sh(sh: Tensor, dirs: Tensor) -> Tensor:  # [N, K, 3], [N, 3] unit -> [N, 3]
    """Evaluate real SH (degree from K) in directions ``dirs`` (3DGS convention, no +0.5)."""
    deg = sh_degree_from_k(sh.shape[-2])
    res = SH_C0 * sh[:, 0]
    if deg < 1:
        return res
    x, y, z = (dirs[:, i:i + 1] for i in range(3))
    res = res - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if deg < 2:
        return res
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    res = (res + SH_C2[0] * xy * sh[:, 4] + SH_C2[1] * yz * sh[:, 5]
           + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6] + SH_C2[3] * xz * sh[:, 7]
           + SH_C2[4] * (xx - yy) * sh[:, 8])
    if deg < 3:
        return res
    return (res + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9] + SH_C3[1] * xy * z * sh[:, 10]
            + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
            + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
            + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13]
            + SH_C3[5] * z * (xx - yy) * sh[:, 14] + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15])


def rgb_to_sh0(rgb):
    return (rgb - 0.5) / SH_C0


class _GaussianOps:
    """Derived quantities shared by :class:`Gaussians` and :class:`GaussianTensors`."""

    def __len__(self):
        return self.means.shape[0]

    @property
    def is_sh(self) -> bool:
        return self.colors.ndim == 3

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_k(self.colors.shape[1]) if self.is_sh else -1

    def opacities(self) -> Tensor:  # [N]
        return torch.sigmoid(self.opacity_logits)

    def covariances(self) -> Tensor:  # [N, 3, 3]
        return covariance(self.log_scales, self.quats)

    def rigidly_moved(self, R: Tensor, t: Tensor, pivot: Tensor) -> "GaussianTensors":
        """The Gaussians moved by the rigid motion X' = R (X − pivot) + pivot + t (R [3, 3], t and
        pivot [3]): means moved, rotations turned by R; scales, opacities and colours as they are."""
        quats = quat_mul(rotmat_to_quat_torch(R[None]).expand(len(self), 4), self.quats)
        return GaussianTensors((self.means - pivot) @ R.T + pivot + t, self.log_scales, quats, self.opacity_logits,
                               self.colors)

    def rgb(self, cam_center=None) -> Tensor:  # [N, 3]
        """View-dependent colour seen from ``cam_center`` (3,) (ignored for plain RGB)."""
        if not self.is_sh:
            return self.colors
        c = torch.as_tensor(np.zeros(3) if cam_center is None else cam_center,
                            dtype=self.means.dtype, device=self.means.device)
        d = self.means - c
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return torch.clamp_min(eval_sh(self.colors, d) + 0.5, 0.0)


class GaussianTensors(_GaussianOps):
    """Plain (non-Module) bundle of Gaussian tensors, e.g. outputs of a network or for gradcheck.
    Same fields and methods as :class:`Gaussians`; tensors keep their autograd graph."""

    def __init__(self, means, log_scales, quats, opacity_logits, colors, parent=None):
        self.means, self.log_scales, self.quats = means, log_scales, quats
        self.opacity_logits, self.colors, self.parent = opacity_logits, colors, parent


def _unit_rgb(colors, n: int) -> np.ndarray:
    """Per-vertex colours as (n, 3) floats in [0, 1]: RGB or RGBA (alpha dropped), floats in [0, 1]
    or integers in [0, 255] (a mesh's ``colors`` as loaded)."""
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise SplatError(f"colors must have shape ({n}, 3) or ({n}, 4); got {c.shape}")
    c = c[:, :3]
    if np.issubdtype(c.dtype, np.integer):
        return c.astype(np.float64) / 255.0
    return np.clip(c.astype(np.float64), 0.0, 1.0)


class Gaussians(_GaussianOps, nn.Module):
    """A set of N 3D Gaussians with learnable parameters.

    Parameters
    ----------
    means : [N, 3]
    log_scales : [N, 3]
    quats : [N, 4]
        (w, x, y, z), normalised in use.
    opacity_logits : [N]
    colors : [N, 3] or [N, K, 3]
        Plain RGB, or SH coefficients with K ∈ {1, 4, 9, 16} (RGB = max(SH(d) + 0.5, 0), as 3DGS).
    parent : [N] int64, optional
        Parent-vertex index (a buffer, kept through densification by the density-control code).
    """

    def __init__(self, means, log_scales, quats, opacity_logits, colors, parent=None):
        super().__init__()
        t = lambda a: torch.as_tensor(a).clone()  # noqa: E731
        means, log_scales, quats, opacity_logits, colors = map(
            t, (means, log_scales, quats, opacity_logits, colors))
        n = means.shape[0]
        for name, a, shp in (("means", means, (n, 3)), ("log_scales", log_scales, (n, 3)),
                             ("quats", quats, (n, 4)), ("opacity_logits", opacity_logits, (n,))):
            if tuple(a.shape) != shp:
                raise SplatError(f"{name} must have shape {shp}; got {tuple(a.shape)}")
        if not (colors.shape == (n, 3) or (colors.ndim == 3 and colors.shape[0] == n
                                          and colors.shape[2] == 3)):
            raise SplatError(f"colors must have shape ({n}, 3) or ({n}, K, 3); got {tuple(colors.shape)}")
        if colors.ndim == 3:
            sh_degree_from_k(colors.shape[1])
        self.means = nn.Parameter(means)
        self.log_scales = nn.Parameter(log_scales)
        self.quats = nn.Parameter(quats)
        self.opacity_logits = nn.Parameter(opacity_logits)
        self.colors = nn.Parameter(colors)
        self.register_buffer("parent", None if parent is None else torch.as_tensor(parent, dtype=torch.int64))

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_mesh(cls, V, F, colors=None, *, sh_degree=0, opacity=0.1, normal_scale=0.1,
                  dtype=torch.float32) -> "Gaussians":
        """One Gaussian per vertex, as THGS: frame from the vertex normal, scale sqrt(A_avg/π).

        The rotation's third column is the (area-weighted) vertex normal; both tangent scales
        are ``sqrt(A_avg / π)`` with ``A_avg`` the mean area of the faces around the vertex and
        the normal scale is ``normal_scale`` times that (so the normal is the smallest axis).
        ``parent[i] = i``. ``colors``: (n, 3) or (n, 4) per vertex, floats in [0, 1] or integers
        in [0, 255] (a loaded mesh's ``colors`` as they are); grey when None.
        """
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        if V.ndim != 2 or V.shape[1] != 3:
            raise SplatError(f"V must have shape (n, 3); got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3:
            raise SplatError(f"F must have shape (m, 3); got {F.shape}")
        if len(F) == 0 or F.min() < 0 or F.max() >= len(V):
            raise SplatError("F is empty or indexes vertices out of range")
        n = len(V)
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # 2·area·unit normal
        area = 0.5 * np.linalg.norm(fn, axis=1)
        vn = np.zeros((n, 3))
        asum = np.zeros(n)
        cnt = np.zeros(n)
        for k in range(3):
            np.add.at(vn, F[:, k], fn)
            np.add.at(asum, F[:, k], area)
            np.add.at(cnt, F[:, k], 1)
        a_avg = np.where(cnt > 0, asum / np.maximum(cnt, 1), np.mean(area))
        s = np.sqrt(np.maximum(a_avg, 1e-20) / np.pi)
        nl = np.linalg.norm(vn, axis=1, keepdims=True)
        vn = np.where(nl > 1e-20, vn / np.maximum(nl, 1e-300), [0.0, 0.0, 1.0])
        # tangent frame: t1 ⟂ n from the world axis least aligned with n
        helper = np.eye(3)[np.argmin(np.abs(vn), 1)]
        t1 = np.cross(helper, vn)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(vn, t1)
        R = np.stack([t1, t2, vn], axis=2)  # columns
        quats = rotmat_to_quat(R)
        log_scales = np.log(np.stack([s, s, s * normal_scale], 1))
        cols = np.full((n, 3), 0.5) if colors is None else _unit_rgb(colors, n)
        sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
        sh[:, 0] = rgb_to_sh0(cols)
        logit = np.log(opacity / (1 - opacity))
        tt = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
        return cls(tt(V), tt(log_scales), tt(quats), tt(np.full(n, logit)), tt(sh),
                   parent=torch.arange(n))

    @classmethod
    def from_points(cls, P, colors=None, *, k=3, sh_degree=0, opacity=0.1,
                    dtype=torch.float32) -> "Gaussians":
        """Isotropic Gaussians at points ``P`` (n, 3); scale = mean distance to the k nearest."""
        P = np.asarray(P, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
            raise SplatError(f"P must have shape (n, 3) with n >= 2; got {P.shape}")
        from scipy.spatial import cKDTree
        kk = min(k, len(P) - 1)
        d, _ = cKDTree(P).query(P, kk + 1)
        s = np.maximum(d[:, 1:].mean(1), 1e-7)
        n = len(P)
        cols = np.full((n, 3), 0.5) if colors is None else np.asarray(colors, dtype=np.float64)
        sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
        sh[:, 0] = rgb_to_sh0(cols)
        q = np.tile([1.0, 0, 0, 0], (n, 1))
        tt = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
        return cls(tt(P), tt(np.log(np.repeat(s[:, None], 3, 1))), tt(q),
                   tt(np.full(n, np.log(opacity / (1 - opacity)))), tt(sh))
