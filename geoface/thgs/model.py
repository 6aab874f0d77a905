"""THGS building blocks: forward LBS with voxel skinning, learnable expression blendshapes, and the
Spatial Audio Attention Module (Chen et al., "THGS: talking human avatars with Gaussian splatting").

* :func:`joint_transforms` (eq. 4–5): per joint the world transform G_j(θ) · G_j(0)⁻¹ of the
  kinematic chain for local joint rotations θ (axis-angle, [J, 3]) and a root translation.
* :class:`VoxelSkinning` (eq. 6–7, 18): skinning weights stored in an R³ grid (R = 64) over the
  template's padded bounding box — each grid point the inverse-distance average of its k nearest
  template vertices' weights — looked up trilinearly; learnable grid offsets ΔW (zero at start),
  normalised w = relu(w₀ + ΔW) / Σ relu(w₀ + ΔW).
* :func:`lbs` (eq. 7): x' = Σ_j w_j A_j x; each Gaussian's rotation is the normalised blend
  Σ_j w_j q_j of the joints' quaternions (one hemisphere) composed with its own — smooth, where
  the polar factor of Σ_j w_j R_j has an SVD whose gradient is singular for equal rotations.
* :class:`ExpressionBlendshapes` (eq. 8–9): Ê = E + ΔE ∘ M_H with ΔE zero at start and confined
  to the head mask M_H; vertex offsets Σ_k ψ_k Ê_k; L2 penalty ‖ΔE‖² (weight 0.1 in training).
* training (:func:`train_thgs`): 0.8·L1 + 0.2·D-SSIM, vertex loss (eq. 19, weight 1e-2), LEB
  penalty (0.1), in the refinement stage a normal loss (:meth:`THGSModel.normal_loss`) and, when
  the capture has a tracker's ``landmarks.json``, the mouth landmarks (ours; thgs_data).
* :class:`SpatialAudioAttention` (eq. 10–15): the mouth Gaussians (inside the teeth box + 0.02)
  encoded by a multiresolution tri-plane hash encoding, fused with the frame's audio features,
  passed through external attention (two learned memories, double normalisation) and a
  4-layer MLP predicting Δμ, Δr (quaternion offset), Δs (log scale). The output is taken
  relative to silence — Δ(x, a) = g(x, a) − g(x, 0) — so zero audio moves nothing for any
  weights (the canonical mouth is the silent mouth), and the last layer starts at zero.
* :class:`AudioArticulation` (ours): where the tracker measures no jaw or mouth (``poses.npz``'s
  masks), those DOFs come from the audio through a small MLP, from the expression stage on; the
  paper takes them from its tracker. ``use_audio_pose=False`` leaves them at rest.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as Fnn
from torch import Tensor, nn

from geoface.mesh.core import vertex_normals
from geoface.splat.errors import SplatError
from geoface.avatar.corrections import FrameCorrections
from geoface.splat.gaussians import Gaussians, GaussianTensors, quat_mul, quat_to_rotmat, rotmat_to_quat_torch
from geoface.avatar.kinematics import axis_angle_to_matrix, joint_transforms, skin_points

__all__ = ["axis_angle_to_matrix", "joint_transforms", "VoxelSkinning", "lbs", "rotmat_to_quat_torch",
           "ExpressionBlendshapes", "SpatialAudioAttention", "AudioArticulation", "ExternalAttention", "mouth_gaussians",
           "THGSConfig", "THGSModel", "train_thgs", "save_thgs", "load_thgs", "render_frames", "animate"]


class VoxelSkinning(nn.Module):
    """Skinning weights in a ``res``³ grid over the template's bounding box (module doc)."""

    def __init__(self, V, weights, res: int = 64, k: int = 4, pad: float = 0.1, learn_offsets: bool = True):
        super().__init__()
        from scipy.spatial import cKDTree

        V = np.asarray(V, np.float64)
        W = np.asarray(weights, np.float64)
        lo, hi = V.min(0), V.max(0)
        ext = hi - lo
        lo, hi = lo - pad * ext, hi + pad * ext
        g = [np.linspace(lo[i], hi[i], res) for i in range(3)]
        P = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        d, j = cKDTree(V).query(P, k=k)
        d, j = d.reshape(len(P), k), j.reshape(len(P), k)
        w = 1.0 / (d + 1e-9)
        G = (W[j] * w[..., None]).sum(1) / w.sum(1, keepdims=True)
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


# ============================================================================ the avatar

PAPER_STAGES = (1500, 15000, 25000, 50000)  # skinning & pose, expression, blendshapes, SAAM
PAPER_ITERS = 150000  # Table 1: 150K steps in all, so SAAM starts at a third of training


@dataclass
class THGSConfig:
    """Training settings. ``stage_scale`` maps the paper's stage starts (Table 1: skinning and pose
    from step 1500, expression 15K, blendshapes 25K, SAAM 50K, of 150K) onto this run: None =
    ``iters / 150000`` (the same fractions of the run as the paper's)."""

    iters: int = 3000
    stage_scale: float | None = None
    voxel_res: int = 64
    use_leb: bool = True
    use_saam: bool = True
    #: the untracked DOFs (jaw, mouth blendshapes) driven by the audio (:class:`AudioArticulation`)
    use_audio_pose: bool = True
    lambda_dssim: float = 0.2
    lambda_vertex: float = 1e-2
    lambda_leb: float = 0.1
    lambda_normal: float = 0.01   # refinement stage (from the blendshape stage on)
    lambda_landmarks: float = 3.0  # mouth landmarks (landmarks.json) from the expression stage on
    #: fit the audio articulation to the training frames' mouth landmarks when it switches on (thgs_prefit)
    artic_prefit: bool = False
    audio_window: int = 2  # SAAM and the audio articulation read the features of this many frames each side too
    landmarks_pose: bool = False   # True: the landmark term also moves the per-frame pose corrections
    lr_means: float = 1.6e-4
    lr_nets: float = 1e-3
    lr_pose: float = 1e-2  # per-frame corrections: radians per step at a typical misfit (FrameCorrections)
    pose_decay: float = 10.0  # … falling this many times, exponentially, from their first step to the last
    heldout: float = 0.2
    init_opacity: float = 0.5
    seed: int = 0
    threads: int | None = None

    def __post_init__(self):
        if self.audio_window < 0:
            raise SplatError(f"THGSConfig.audio_window must be >= 0 frames; got {self.audio_window}")
        if not (self.lr_pose > 0 and self.pose_decay >= 1):
            raise SplatError(f"THGSConfig: need lr_pose > 0 and pose_decay >= 1; got {self.lr_pose}, {self.pose_decay}")
        if self.iters < 1 or self.voxel_res < 2 or not 0 <= self.heldout < 1:
            raise SplatError(f"bad THGS config: iters={self.iters}, voxel_res={self.voxel_res}, heldout={self.heldout}")

    def stages(self) -> tuple[int, ...]:
        s = self.iters / PAPER_ITERS if self.stage_scale is None else self.stage_scale
        return tuple(int(round(v * s)) for v in PAPER_STAGES)

    @classmethod
    def from_dict(cls, d, where: str = "THGS config"):
        from geoface.nn.config import config_from_dict

        from geoface.splat.errors import ModelFolderError

        # saved before the audio articulation: none; before landmarks_pose: the landmarks moved the poses;
        # before audio_window: one frame's features; before pose_decay: a constant rate
        return config_from_dict(cls, {"use_audio_pose": False, "landmarks_pose": True, "audio_window": 0, "pose_decay": 1.0,
                                      **d}, where=where,
                                error=ModelFolderError)


class THGSModel(nn.Module):
    """Gaussians bound to template vertices, posed by voxel LBS, with LEB and SAAM (module doc)."""

    def __init__(self, tpl, cfg: THGSConfig, audio_dim: int, n_frames: int = 0, gaussians: Gaussians | None = None):
        super().__init__()
        self.cfg = cfg
        self.audio_dim = audio_dim  # features per frame; the networks read 2 audio_window + 1 frames of them
        audio_dim = audio_dim * (2 * cfg.audio_window + 1)
        self.template = tpl
        C = np.full((len(tpl.V), 3), 0.5)
        self.gaussians = gaussians or Gaussians.from_mesh(tpl.V, tpl.F, C, opacity=cfg.init_opacity)
        if self.gaussians.parent is None:
            self.gaussians.parent = torch.arange(len(tpl.V))
        self.register_buffer("V0", torch.tensor(tpl.V, dtype=torch.float32))
        self.register_buffer("joints", torch.tensor(tpl.joints, dtype=torch.float32))
        self.register_buffer("vertex_normals", torch.tensor(vertex_normals(tpl.V, tpl.F), dtype=torch.float32))
        self.parents = [int(p) for p in tpl.parents]
        self.skin = VoxelSkinning(tpl.V, tpl.weights, res=cfg.voxel_res)
        self.leb = ExpressionBlendshapes(tpl.expr_basis, tpl.head_mask)
        self.saam = SpatialAudioAttention(tpl.mouth_box, audio_dim, seed=cfg.seed) if cfg.use_saam else None
        self.register_buffer("audio_ref", torch.zeros(audio_dim))   # silence
        self.register_buffer("audio_scale", torch.ones(audio_dim))
        J, K = len(tpl.joints), tpl.n_expr
        self.artic = AudioArticulation(audio_dim, J, K) if cfg.use_audio_pose else None
        self.register_buffer("tracked_joints", torch.ones(J, dtype=torch.bool))  # training sets them
        self.register_buffer("tracked_expr", torch.ones(K, dtype=torch.bool))
        self.d_rot = nn.Parameter(torch.zeros(n_frames, J, 3))     # per-frame pose corrections
        self.d_transl = nn.Parameter(torch.zeros(n_frames, 3))    # … and root translation corrections
        self.d_expr = nn.Parameter(torch.zeros(n_frames, K))      # per-frame expression corrections
        self.stage = 4  # all parts on (training sets it)

    def audio_input(self, features) -> Tensor:
        """[T, D] per-frame audio features → [T, (2 audio_window + 1) D], what :meth:`forward`
        takes per frame (:func:`~geoface.avatar.audio.audio_context`)."""
        from geoface.avatar.audio import audio_context

        return torch.as_tensor(audio_context(features, self.cfg.audio_window))

    def normalize_audio(self, a: Tensor) -> Tensor:
        return (a - self.audio_ref) / self.audio_scale

    def forward(self, rot, transl, expr, audio=None, frame: int | None = None) -> GaussianTensors:
        g = self.gaussians
        dev = self.V0.device
        rot, transl, expr = (torch.as_tensor(a, dtype=torch.float32, device=dev) for a in (rot, transl, expr))
        if audio is not None:
            audio = torch.as_tensor(audio, dtype=torch.float32, device=dev)
        if frame is not None and len(self.d_rot):
            if self.stage >= 1:
                rot = rot + self.d_rot[frame]
                transl = transl + self.d_transl[frame]
            if self.stage >= 2:
                expr = expr + self.d_expr[frame]
        if self.artic is not None and audio is not None and self.stage >= 2:
            dr, de = self.artic(self.normalize_audio(audio))
            rot = rot + dr * (~self.tracked_joints)[:, None]
            expr = expr + de * ~self.tracked_expr
        Xc = g.means
        D = self.leb(expr, learned=self.cfg.use_leb and self.stage >= 3)  # [n_vertices, 3]
        X = Xc + D[g.parent]
        quats, log_scales = g.quats, g.log_scales
        if self.saam is not None and audio is not None and self.stage >= 4:
            m = mouth_gaussians(Xc.detach(), self.saam.box, self.saam.margin)
            if bool(m.any()):
                d = self.saam(Xc[m], self.normalize_audio(audio))
                X = X.clone()
                X[m] = X[m] + d[:, :3] * 0.01
                one = torch.tensor([1.0, 0, 0, 0], device=dev)
                quats = quats.clone()
                quats[m] = quat_mul(quats[m] / quats[m].norm(dim=-1, keepdim=True), one + d[:, 3:7])
                log_scales = log_scales.clone()
                log_scales[m] = log_scales[m] + d[:, 7:]
        W = self.skin(Xc)
        A = joint_transforms(self.joints, self.parents, rot, transl)
        Xp, qp = lbs(X, quats, W, A)
        return GaussianTensors(Xp, log_scales, qp, g.opacity_logits, g.colors)

    def normal_loss(self) -> Tensor:
        """Refinement-stage normal loss: 1 − |n_g · n_v| between each Gaussian's normal (the axis of
        its smallest scale) and its parent vertex's template normal (a geometric stand-in for the
        paper's normal supervision, which needs normal maps of the video)."""
        g = self.gaussians
        R = quat_to_rotmat(g.quats)
        k = torch.argmin(g.log_scales.detach(), dim=1)
        n = R.gather(2, k[:, None, None].expand(-1, 3, 1))[..., 0]
        return (1 - (n * self.vertex_normals[g.parent]).sum(-1).abs()).mean()

    def gaussians_of(self, vertices) -> list[Tensor]:
        """For each template vertex in ``vertices``, the indices of the Gaussians bound to it."""
        out = [torch.nonzero(self.gaussians.parent == int(v))[:, 0] for v in vertices]
        if not all(len(i) for i in out):
            raise SplatError("no Gaussian is bound to one of the vertices " + str([int(v) for v in vertices]))
        return out

    def vertex_loss(self) -> Tensor:
        """Eq. 19: mean squared distance of each Gaussian to its parent vertex (metres²)."""
        g = self.gaussians
        return ((g.means - self.V0[g.parent]) ** 2).sum(-1).mean()


def train_heldout_split(n: int, heldout: float):
    k = max(1, int(round(n * (1 - heldout)))) if heldout > 0 else n
    return np.arange(k), np.arange(k, n)


def train_thgs(data_dir, out_dir, cfg: THGSConfig | None = None, *, progress=None, log=print,
               device: str = "cpu") -> dict:
    """Fit a THGS avatar to a talking data folder (first 1 − heldout of the frames).  ``device``:
    "cpu" or "cuda" (the gsplat rasteriser when installed, else the torch one on the GPU); the
    saved model is the same either way."""
    from geoface.nn.config import resolve_device
    from geoface.nn.losses import dssim
    from geoface.progress import progress as bar
    from geoface.splat.density import make_optimizer
    from geoface.splat.rasterizer import rasterize
    from geoface.thgs.data import landmark_loss, load_talking, mouth_landmark_targets
    from geoface.thgs.prefit import prefit_training

    cfg = cfg or THGSConfig()
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    data = load_talking(data_dir)
    tr, _ = train_heldout_split(len(data), cfg.heldout)
    model = THGSModel(data.template, cfg, data.audio.shape[1], len(data))
    A = model.audio_input(data.audio)
    model.audio_ref.copy_(torch.quantile(A[tr], 0.02, dim=0))
    model.audio_scale.copy_(A[tr].std(0).clamp_min(1e-3))
    model.tracked_joints.copy_(torch.as_tensor(data.tracked_joints))
    model.tracked_expr.copy_(torch.as_tensor(data.tracked_expr))
    dev = resolve_device(device, SplatError) or "cpu"
    model.to(dev)
    A = A.to(dev)
    g = model.gaussians
    ext = float(np.ptp(data.template.V, 0).max())
    opt = make_optimizer(g, {"means": cfg.lr_means * ext, "log_scales": 5e-3, "quats": 1e-3,
                             "opacity_logits": 2.5e-2, "colors": 1e-2}, eps=1e-15)
    opt.add_param_group({"params": [model.skin.offsets], "lr": cfg.lr_nets * 0.1, "name": "skin"})
    # what the tracker did not measure (a jaw, lips left to the audio) gets no per-frame correction:
    # one would fit each training frame's mouth and leave the audio module nothing to learn;
    # translation corrections in metres: the rotation's step times the head's size
    frame_opt = FrameCorrections([(model.d_rot, cfg.lr_pose, torch.tensor(data.tracked_joints)[:, None]),
                                  (model.d_transl, cfg.lr_pose * ext),
                                  (model.d_expr, cfg.lr_pose, torch.tensor(data.tracked_expr))])
    opt.add_param_group({"params": [model.leb.delta], "lr": cfg.lr_nets * 0.01, "name": "leb"})
    if model.saam is not None:
        opt.add_param_group({"params": list(model.saam.parameters()), "lr": cfg.lr_nets, "name": "saam"})
    if model.artic is not None:
        opt.add_param_group({"params": list(model.artic.parameters()), "lr": cfg.lr_nets, "name": "artic"})
    imgs = torch.tensor(data.frames, device=dev)
    lmk = mouth_landmark_targets(data) if cfg.lambda_landmarks > 0 else None
    if lmk is not None:  # the Gaussian bound to each landmark's vertex
        lmk = ([int(i[0]) for i in model.gaussians_of(lmk[0])], lmk[1])
    stages = cfg.stages()
    history, order = [], []
    bg = torch.zeros(3, device=dev)
    t0 = time.perf_counter()
    steps = range(cfg.iters)
    if not callable(progress):
        steps = bar(steps, "training THGS", total=cfg.iters, quiet=None if progress is None else not progress)
    prefit = None
    for it in steps:
        model.stage = sum(it >= s for s in stages)
        if model.stage >= 2 and prefit is None:
            prefit = prefit_training(model, data, tr, A, lmk) if cfg.artic_prefit else {}
        if not order:
            order = list(rng.permutation(tr))
        f = int(order.pop())
        gd = model(data.rot[f], data.transl[f], data.expr[f], A[f], frame=f)
        rgb = rasterize(gd, data.camera, background=bg)[0]
        gt = imgs[f]
        l1 = (rgb - gt).abs().mean()
        loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * dssim(rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])
        loss = loss + cfg.lambda_vertex * model.vertex_loss() / ext**2
        lm = (cfg.lambda_landmarks * landmark_loss(gd.means[lmk[0]], data.camera, lmk[1][f])
              if lmk is not None and model.stage >= 2 else None)
        if lm is not None and cfg.landmarks_pose:
            loss, lm = loss + lm, None
        if model.stage >= 3:
            if cfg.use_leb:
                loss = loss + cfg.lambda_leb * model.leb.penalty() / ext**2
            loss = loss + cfg.lambda_normal * model.normal_loss()
        if lm is not None:  # the landmark term's gradient reaches the networks, not the pose corrections
            lm.backward(retain_graph=True)
            frame_opt.zero_grad()
        loss.backward()
        loss = loss if lm is None else loss + lm.detach()
        for grp in opt.param_groups:  # staged schedule: parts not yet switched on keep still
            name = grp["name"]
            on = {"skin": model.stage >= 1, "leb": model.stage >= 3 and cfg.use_leb,
                  "saam": model.stage >= 4, "artic": model.stage >= 2}.get(name, True)
            if not on:
                for p in grp["params"]:
                    p.grad = None
        opt.step()
        opt.zero_grad(set_to_none=True)
        if model.stage >= 1:  # pose corrections from the first stage (expression ones act from the second)
            frame_opt.step(f, cfg.pose_decay ** -((it - stages[0]) / max(cfg.iters - 1 - stages[0], 1)))
        frame_opt.zero_grad()
        history.append({"step": it, "loss": float(loss.detach()), "l1": float(l1.detach()), "stage": model.stage})
        if callable(progress) and (it % 50 == 0 or it == cfg.iters - 1):
            progress(it, history[-1])
    save_thgs(model.cpu(), out_dir)
    from geoface.avatar.capture import camera_to_json
    (Path(out_dir) / "camera.json").write_text(json.dumps(camera_to_json(data.camera)))
    return {"seconds": time.perf_counter() - t0, "history": history, "stages": stages, "n_gaussians": len(g),
            "artic_prefit": prefit or {}}


def save_thgs(model: THGSModel, out_dir) -> None:
    from geoface.avatar.model_dir import write_model_dir

    out = write_model_dir(out_dir, model, {"format": "geoface-thgs", "version": 1, "config": asdict(model.cfg),
                                           "audio_dim": int(model.audio_dim),
                                           "n_frames": int(model.d_rot.shape[0])})
    model.template.save(out / "template.npz")


def load_thgs(model_dir) -> THGSModel:
    from geoface.avatar.model_dir import load_model_state, read_model_config
    from geoface.avatar.template import Template

    from geoface.splat.errors import ModelFolderError

    d, meta = read_model_config(model_dir, "geoface-thgs", "THGS")
    cfg = THGSConfig.from_dict(meta["config"], where=f"{d}/config.json")
    for key in ("audio_dim", "n_frames"):
        if isinstance(meta.get(key), bool) or not isinstance(meta.get(key), int) or meta[key] < 0:
            raise ModelFolderError(f"{d}/config.json: {key} must be a non-negative integer; got {meta.get(key)!r}")
    sd = load_model_state(d / "model.safetensors")
    tpl = Template.load(d / "template.npz")
    try:
        g = Gaussians(sd["gaussians.means"], sd["gaussians.log_scales"], sd["gaussians.quats"],
                      sd["gaussians.opacity_logits"], sd["gaussians.colors"], sd["gaussians.parent"])
        model = THGSModel(tpl, cfg, int(meta["audio_dim"]), int(meta["n_frames"]), g)
        sd.setdefault("d_transl", torch.zeros_like(model.d_transl))  # saved before translation corrections
        sd.setdefault("tracked_joints", model.tracked_joints)  # ... and before the tracked masks
        sd.setdefault("tracked_expr", model.tracked_expr)
        model.load_state_dict(sd, strict=True)
    except (KeyError, RuntimeError) as e:
        raise SplatError(f"{d}: weights do not match config.json ({str(e).splitlines()[0][:160]})") from None
    model.eval()
    model._dir = str(d)
    return model


@torch.no_grad()
def render_frames(model: THGSModel, camera, rot, transl, expr, audio, frames=None):
    """Render poses (and audio features) → ([T, H, W, 3] float32, per-frame seconds)."""
    from geoface.splat.rasterizer import rasterize

    out, times = [], []
    bg = torch.zeros(3)
    idx = range(len(rot)) if frames is None else frames
    audio = None if audio is None else model.audio_input(audio)
    for t in idx:
        t0 = time.perf_counter()
        gd = model(rot[t], transl[t], expr[t], None if audio is None else audio[t])
        out.append(rasterize(gd, camera, background=bg)[0].clamp(0, 1).numpy())
        times.append(time.perf_counter() - t0)
    return np.stack(out), np.asarray(times)


def animate(model: THGSModel, audio_path, out_dir=None, *, poses=None, fps: float = 25.0, camera=None):
    """Drive the avatar by speech (a WAV, or a .npy/.npz of per-frame features) and optional poses
    (.npz with rot/transl/expr; default: the rest pose, neutral expression). Writes
    ``out_dir/frames/*.png`` when given; returns (frames [T, H, W, 3], per-frame seconds)."""
    from geoface.avatar.audio import audio_features, read_wav
    from geoface.avatar.capture import camera_from_json, write_frame
    from geoface.thgs.data import load_poses

    p = Path(audio_path)
    if p.suffix.lower() == ".wav":
        x, sr = read_wav(p)
        T = max(1, int(len(x) / sr * fps))
    else:
        T = None
    J, K = len(model.template.joints), model.template.n_expr
    if poses is not None:
        rot, transl, expr = load_poses(poses, J, K)
        T = len(rot) if T is None else min(T, len(rot))
    elif T is None:
        raise SplatError("with precomputed audio features give --poses (they fix the frame count)")
    A = audio_features(p, T, fps)
    if A.shape[1] != model.audio_dim:
        raise SplatError(f"{p}: {A.shape[1]} audio features per frame; the model was trained on {model.audio_dim}")
    if poses is None:
        rot, transl, expr = np.zeros((T, J, 3)), np.zeros((T, 3)), np.zeros((T, K))
    if camera is None:
        cam_path = Path(getattr(model, "_dir", "")) / "camera.json"
        if not cam_path.is_file():
            raise SplatError("no camera: the model folder has no camera.json")
        camera = camera_from_json(cam_path)
    frames, times = render_frames(model, camera, rot[:T], transl[:T], expr[:T], A)
    if out_dir is not None:
        for t, img in enumerate(frames):
            write_frame(out_dir, t, img)
    return frames, times

