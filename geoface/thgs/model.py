"""The THGS model: forward LBS with voxel skinning, learnable expression blendshapes, and the
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

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from geoface.mesh.core import vertex_normals
from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians, GaussianTensors, quat_mul, quat_to_rotmat, rotmat_to_quat_torch
from geoface.avatar.kinematics import axis_angle_to_matrix, joint_transforms
from geoface.thgs.blocks import AudioArticulation, ExpressionBlendshapes, SpatialAudioAttention, VoxelSkinning, lbs, mouth_gaussians

__all__ = ["axis_angle_to_matrix", "joint_transforms", "VoxelSkinning", "lbs", "rotmat_to_quat_torch",
           "ExpressionBlendshapes", "SpatialAudioAttention", "AudioArticulation", "ExternalAttention", "mouth_gaussians",
           "THGSConfig", "THGSModel", "train_thgs", "save_thgs", "load_thgs", "render_frames", "animate"]
















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
            raise AvatarError(f"THGSConfig.audio_window must be >= 0 frames; got {self.audio_window}")
        if not (self.lr_pose > 0 and self.pose_decay >= 1):
            raise AvatarError(f"THGSConfig: need lr_pose > 0 and pose_decay >= 1; got {self.lr_pose}, {self.pose_decay}")
        if self.iters < 1 or self.voxel_res < 2 or not 0 <= self.heldout < 1:
            raise AvatarError(f"bad THGS config: iters={self.iters}, voxel_res={self.voxel_res}, heldout={self.heldout}")

    def stages(self) -> tuple[int, ...]:
        s = self.iters / PAPER_ITERS if self.stage_scale is None else self.stage_scale
        return tuple(int(round(v * s)) for v in PAPER_STAGES)

    @classmethod
    def from_dict(cls, d, where: str = "THGS config"):
        from geoface.nn.config import config_from_dict

        from geoface.errors import ModelFolderError

        # saved before the audio articulation: none; before landmarks_pose: the landmarks moved the poses;
        # before audio_window: one frame's features; before pose_decay: a constant rate
        return config_from_dict(cls, {"use_audio_pose": False, "landmarks_pose": True, "audio_window": 0, "pose_decay": 1.0,
                                      **d}, where=where,
                                error=ModelFolderError)


class THGSModel(nn.Module):
    """Gaussians bound to template vertices, posed by voxel LBS, with LEB and SAAM (module doc)."""

    #: the ``format`` of its config.json and its verb group (the avatar contract, :class:`geoface.thgs.avatar.THGSAvatar`)
    FORMAT = "geoface-thgs"
    KIND = "thgs"

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
            raise AvatarError("no Gaussian is bound to one of the vertices " + str([int(v) for v in vertices]))
        return out

    def vertex_loss(self) -> Tensor:
        """Eq. 19: mean squared distance of each Gaussian to its parent vertex (metres²)."""
        g = self.gaussians
        return ((g.means - self.V0[g.parent]) ** 2).sum(-1).mean()













