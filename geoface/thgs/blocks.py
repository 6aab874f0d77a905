"""The networks of THGS: the voxel skinning grid and linear blend skinning (eq. 4-6), learnable
expression blendshapes, and the spatial audio attention module (external attention over audio
features) with the audio articulation head."""
from __future__ import annotations


import numpy as np
import torch
import torch.nn.functional as Fnn
from torch import Tensor, nn

from geoface.splat.gaussians import quat_mul, rotmat_to_quat_torch
from geoface.avatar.kinematics import skin_points


class VoxelSkinning(nn.Module):
    """Skinning weights in a ``res``³ grid over the template's bounding box (module doc)."""

    def __init__(self, V, weights, res: int = 64, k: int = 4, pad: float = 0.1, learn_offsets: bool = True):
        super().__init__()
        lo, hi, G = _grid_weights(np.asarray(V, np.float64), np.asarray(weights, np.float64), int(res), int(k), float(pad))
        self.res = res
        self.register_buffer("lo", torch.tensor(lo, dtype=torch.float32))
        self.register_buffer("hi", torch.tensor(hi, dtype=torch.float32))
        grid = torch.tensor(G.reshape(res, res, res, -1), dtype=torch.float32).permute(3, 0, 1, 2)
        self.register_buffer("grid", grid.contiguous())  # [J, R, R, R] (x, y, z)
        self.offsets = nn.Parameter(torch.zeros_like(grid)) if learn_offsets else None

    def forward(self, X: Tensor) -> Tensor:  # [N, 3] -> [N, J]
        u = (X - self.lo) / (self.hi - self.lo) * 2 - 1  # grid_sample: x ↔ last dim (z here)
        G = self.grid if self.offsets is None else Fnn.relu(self.grid + self.offsets)
        s = Fnn.grid_sample(G[None], u.flip(-1)[None, :, None, None], mode="bilinear", padding_mode="border",
                            align_corners=True)[0, :, :, 0, 0].T
        return s / s.sum(1, keepdim=True).clamp_min(1e-12)


#: the last few templates' grids (a model is built again for every load, resume and evaluation
#: of the same person: the grid's nearest-vertex query is the costly part)
_GRIDS: dict = {}
_GRID_CACHE = 4


def _grid_weights(V: np.ndarray, W: np.ndarray, res: int, k: int, pad: float):
    """``(lo, hi, G (res³, J))``: the grid's corners and each node's skinning weights, the
    inverse-distance blend of its ``k`` nearest template vertices' (:class:`VoxelSkinning`)."""
    import hashlib

    from scipy.spatial import cKDTree

    h = hashlib.sha1(np.ascontiguousarray(V).tobytes())
    h.update(np.ascontiguousarray(W).tobytes())
    key = (h.hexdigest(), V.shape, W.shape, res, k, pad)
    if key not in _GRIDS:
        lo, hi = V.min(0), V.max(0)
        ext = hi - lo
        lo, hi = lo - pad * ext, hi + pad * ext
        g = [np.linspace(lo[i], hi[i], res) for i in range(3)]
        P = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        d, j = cKDTree(V).query(P, k=k)
        d, j = d.reshape(len(P), k), j.reshape(len(P), k)
        w = 1.0 / (d + 1e-9)
        _GRIDS[key] = (lo, hi, (W[j] * w[..., None]).sum(1) / w.sum(1, keepdims=True))
        while len(_GRIDS) > _GRID_CACHE:
            _GRIDS.pop(next(iter(_GRIDS)))
    return _GRIDS[key]


def lbs(X: Tensor, quats: Tensor, W: Tensor, A: Tensor) -> tuple[Tensor, Tensor]:
    """Posed means and quaternions: x' = Σ w_j A_j x, q' = normalise(Σ w_j q_j) ⊗ q."""
    Xp = skin_points(X, W, A)
    qj = rotmat_to_quat_torch(A[:, :3, :3])
    qj = qj * torch.where(qj[:, :1] < 0, -1.0, 1.0)  # one hemisphere
    qb = W.to(qj.dtype) @ qj
    return Xp, quat_mul(qb / qb.norm(dim=-1, keepdim=True), quats / quats.norm(dim=-1, keepdim=True))


class ExpressionBlendshapes(nn.Module):
    """LEB: Ê = E + ΔE ∘ M_H (eq. 8–9)."""

    def __init__(self, basis, head_mask):
        super().__init__()
        self.register_buffer("E", torch.as_tensor(np.asarray(basis), dtype=torch.float32))
        self.register_buffer("mask", torch.as_tensor(np.asarray(head_mask), dtype=torch.float32)[None, :, None])
        self.delta = nn.Parameter(torch.zeros_like(self.E))

    def basis(self) -> Tensor:
        return self.E + self.delta * self.mask

    def forward(self, psi: Tensor, learned: bool = True) -> Tensor:  # [K] -> [n, 3]
        B = self.basis() if learned else self.E
        return torch.einsum("k,knc->nc", psi, B)

    def penalty(self) -> Tensor:
        return ((self.delta * self.mask) ** 2).sum(-1).mean()


def mouth_gaussians(X, box, margin: float = 0.02) -> Tensor:
    """Bool [N]: inside the mouth/teeth box grown by ``margin`` (THGS: teeth bbox + 0.02)."""
    box = box.to(X) if torch.is_tensor(box) else torch.as_tensor(np.asarray(box), dtype=X.dtype, device=X.device)
    return ((X >= box[0] - margin) & (X <= box[1] + margin)).all(-1)


class ExternalAttention(nn.Module):
    """External attention (Guo et al. 2021): A = double-norm(F M_kᵀ), out = A M_v, residual."""

    def __init__(self, dim: int, memory: int = 64):
        super().__init__()
        self.mk = nn.Linear(dim, memory, bias=False)
        self.mv = nn.Linear(memory, dim, bias=False)

    def forward(self, F: Tensor) -> Tensor:  # [N, dim]
        a = torch.softmax(self.mk(F), dim=0)  # normalise over the tokens ...
        a = a / (a.sum(-1, keepdim=True) + 1e-9)  # ... then over the memory slots
        return F + self.mv(a)


class SpatialAudioAttention(nn.Module):
    """SAAM (module doc): mouth Gaussians' Δμ, Δr, Δs from their position and the audio."""

    def __init__(self, box, audio_dim: int, *, margin: float = 0.02, hidden: int = 64, audio_hidden: int = 32,
                 levels: int = 8, features: int = 2, log2_table: int = 12, memory: int = 64, seed: int = 0):
        super().__init__()
        from geoface.nn.hashenc import TriPlaneHashEncoding

        lo = np.asarray(box, np.float64)[0] - margin
        hi = np.asarray(box, np.float64)[1] + margin
        self.margin = margin
        self.register_buffer("box", torch.tensor(np.stack([lo + margin, hi - margin]), dtype=torch.float32))
        self.enc = TriPlaneHashEncoding((lo, hi), levels=levels, features=features, log2_table=log2_table,
                                        max_res=128, seed=seed)
        self.audio = nn.Sequential(nn.Linear(audio_dim, audio_hidden), nn.ReLU(), nn.Linear(audio_hidden, audio_hidden))
        d = self.enc.out_dim + audio_hidden
        self.attn = ExternalAttention(d, memory)
        layers = [nn.Linear(d, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                  nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 10)]
        nn.init.zeros_(layers[-1].weight)
        nn.init.zeros_(layers[-1].bias)
        self.mlp = nn.Sequential(*layers)

    def _g(self, e: Tensor, a: Tensor) -> Tensor:
        h = torch.cat([e, self.audio(a).expand(len(e), -1)], -1)
        return self.mlp(self.attn(h))

    def forward(self, X: Tensor, audio: Tensor) -> Tensor:  # [M, 3] mouth Gaussians, [D] -> [M, 10]
        e = self.enc(X)
        return self._g(e, audio[None]) - self._g(e, torch.zeros_like(audio)[None])


class AudioArticulation(nn.Module):
    """What the tracker does not measure (the jaw, the mouth's blendshapes) from the frame's
    audio: an MLP of the normalised audio features → joint rotations [J, 3] and expression
    weights [K], relative to silence (f(a) − f(0)) and with its last layer zero at start.  The
    model applies it to the untracked DOFs only, so the template's own jaw and lips open the
    mouth (SAAM then refines the mouth Gaussians)."""

    def __init__(self, audio_dim: int, n_joints: int, n_expr: int, hidden: int = 64):
        super().__init__()
        self.J = n_joints
        self.mlp = nn.Sequential(nn.Linear(audio_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, n_joints * 3 + n_expr))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def forward(self, audio: Tensor) -> tuple[Tensor, Tensor]:  # [..., D] -> ([..., J, 3], [..., K])
        o = self.mlp(audio) - self.mlp(torch.zeros_like(audio))
        return o[..., : self.J * 3].unflatten(-1, (self.J, 3)), o[..., self.J * 3:]
