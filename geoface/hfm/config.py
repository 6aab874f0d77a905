"""HFM-GS settings (:class:`HFMConfig`) and the ablations of the paper's Table 3 (:data:`ABLATIONS`)."""
from __future__ import annotations

from dataclasses import asdict, dataclass


from geoface.errors import AvatarError


ABLATIONS = {
    "full": {},
    "no_global_pose": {"global_pose": False},
    "no_gaussian_feature_mapping": {"gaussian_mapping": False},
    "no_gaussian_feature_mapping_separate": {"gaussian_mapping": False, "unmapped_upper": "separate"},
    "no_feature_mapping": {"feature_mapping": False},
    "no_sampling": {"sampling": False},
}


@dataclass
class HFMConfig:
    """Model, loss and training settings (defaults: the paper's where it gives them)."""

    latent_dim: int = 128
    crop: int = 128
    enc_width: int = 32
    pos_freqs: int = 6
    hidden: int = 128
    emb_dim: int = 10          # MLP_gm embeddings
    feat_dim: int = 32         # MLP_pm features
    n_keys: int = 512          # key Gaussians per half
    k_upsample: int = 8        # nearest upper keys in W_dist
    mapping_heads: int = 3     # MLP_mapping as three MLPs, one each for ΔX, ΔS, ΔR as in eq. 2 (3), or one for all (1)
    upsample: str = "features"  # W_dist spreads the keys' mapped features ("features") or their deformations ("params")
    y_split: float | None = None   # y_t (world metres); None: the registration folder's meta.json
    margin: float = 0.004      # m of Algorithm 1 (metres)
    global_pose: bool = True
    pose_residual: bool = False  # MLP_pose(θ) corrects the given head pose (eq. 8 after the tracked pose)
    image_pose: bool = True    # learn the whole head pose from the crop (for videos without head_poses.npz)
    image_pose_detach: bool = False  # its loss trains MLP_head_pose alone, not the encoder (θ detached)
    registration_landmarks: str = "rigid"  # without a pose file, fit registration poses to "rigid", "stable" or "lower" landmarks
    usage_landmarks: str = "lower"  # usage poses are fitted to the 12 "lower" rigid landmarks or their 8 "stable" ones
    pose_calibration: int = 8  # components of the lower-landmark pose calibration learned in registration (0: none)
    pose_calibration_ridge: float = 0.01
    pose_calibration_weighted: bool = True  # its lower-landmark poses weigh each landmark by how little it moved
    pose_calibration_expressions: int = 0  # registration frames seen again with this many generic expressions each (0: none)
    headset_pose: bool = False  # usage poses corrected by where the headset masks lie (geoface.hfm.headset_pose)
    headset_pose_ridge: float = 0.1  # the penalty on its expression map
    pose_align: int = 0        # usage poses from landmarks then aligned with the image: steps per frame (0: not)
    pose_align_translation: bool = False  # the alignment also moves the head, not only turns it
    pose_refine: bool = False  # registration poses fitted to landmarks get per-frame corrections learned with the images
    lr_pose: float = 4e-3      # their step: radians per visit of a frame at a typical misfit (FrameCorrections)
    lambda_pose: float = 100.0  # weight of its loss: squared radians + squared (translation / 0.1 head size)
    gaussian_mapping: bool = True
    feature_mapping: bool = True
    sampling: bool = True
    unmapped_upper: str = "shared"  # without the mapping: upper face by MLP_X/S/R ("shared") or its own MLP
    lower_keys: str = "sample"  # "sample" (∝ correlation weight) or "top" (largest weights)
    detach_lower: bool = True   # the mapping reads the lower deformations without training them
    map_latent_grad: bool = False  # with detach_lower: the upper-face loss still trains θ (the encoder)
    map_norm: bool = True       # the mapping reads p_L / running RMS (per channel) instead of raw p_L
    map_norm_momentum: float = 0.02
    feat_norm: bool = True      # MLP_mapping reads f_U standardised per channel by running statistics
    map_theta: bool = False     # MLP_mapping reads θ beside γ(x_U) and f_U
    gm_input: str = "x"         # MLP_gm embeds γ(x) ("x") or γ(x) with the Gaussian's log-scales and rotation ("xsr")
    pm_per_component: bool = False  # one MLP_pm per deformation component (ΔX, log ΔS, ΔR), each head reads its own
    split_margin: float = 0.0  # d of the boundary losses: the halves are pushed to y_t ± d (metres)
    lambda_rgb: float = 0.4
    lambda_vgg: float = 0.1
    lambda_split: float = 0.01
    vgg_weights: str | None = None
    iters: int = 2000
    warmup: float = 0.2        # fraction of iters that trains the Gaussians alone (static warm-up)
    lr_nets: float = 2e-4     # 1e-3 (batch of one frame) kills ReLU units and collapses θ to a constant
    ema: float = 0.99          # the saved model averages the weights over the last steps (decay per step; 0: last step)
    lr_means: float = 1.6e-4   # × head size (3DGS, scene-scaled)
    key_every: int = 100
    densify: bool = True
    init_opacity: float = 0.5
    seed: int = 0
    threads: int | None = None

    def __post_init__(self):
        for name in ("latent_dim", "crop", "enc_width", "hidden", "emb_dim", "feat_dim", "n_keys",
                     "k_upsample", "iters", "key_every"):
            if int(getattr(self, name)) < 1:
                raise AvatarError(f"HFMConfig.{name} must be >= 1; got {getattr(self, name)!r}")
        if self.crop % 32:
            raise AvatarError(f"HFMConfig.crop must be a multiple of 32 (five stride-2 convolutions); got {self.crop}")
        if self.mapping_heads not in (1, 3):
            raise AvatarError(f"HFMConfig.mapping_heads must be 1 or 3; got {self.mapping_heads!r}")
        if self.unmapped_upper not in ("shared", "separate"):
            raise AvatarError(f"HFMConfig.unmapped_upper must be 'shared' or 'separate'; got {self.unmapped_upper!r}")
        if self.upsample not in ("params", "features"):
            raise AvatarError(f"HFMConfig.upsample must be 'params' or 'features'; got {self.upsample!r}")
        if self.lower_keys not in ("sample", "top"):
            raise AvatarError(f"HFMConfig.lower_keys must be 'sample' or 'top'; got {self.lower_keys!r}")
        if self.margin < 0 or self.split_margin < 0:
            raise AvatarError(f"HFMConfig.margin and split_margin must be >= 0; got {self.margin}, {self.split_margin}")
        if self.pose_calibration < 0 or self.pose_calibration_ridge < 0 or self.pose_calibration_expressions < 0:
            raise AvatarError(f"HFMConfig.pose_calibration, pose_calibration_ridge and pose_calibration_expressions must be "
                             f">= 0; got {self.pose_calibration}, {self.pose_calibration_ridge}, {self.pose_calibration_expressions}")
        if self.pose_align < 0:
            raise AvatarError(f"HFMConfig.pose_align is a number of steps per frame, >= 0; got {self.pose_align!r}")
        if not self.headset_pose_ridge >= 0:
            raise AvatarError(f"HFMConfig.headset_pose_ridge must be >= 0; got {self.headset_pose_ridge!r}")
        if self.registration_landmarks not in ("rigid", "stable", "lower"):
            raise AvatarError("HFMConfig.registration_landmarks must be 'rigid', 'stable' or 'lower'; "
                             f"got {self.registration_landmarks!r}")
        if self.usage_landmarks not in ("lower", "stable"):
            raise AvatarError(f"HFMConfig.usage_landmarks must be 'lower' or 'stable'; got {self.usage_landmarks!r}")
        if self.gm_input not in ("x", "xsr"):
            raise AvatarError(f"HFMConfig.gm_input must be 'x' or 'xsr'; got {self.gm_input!r}")
        if self.pm_per_component and not self.feature_mapping:
            raise AvatarError("HFMConfig.pm_per_component needs feature_mapping (MLP_pm)")
        if not self.lr_pose > 0:
            raise AvatarError(f"HFMConfig.lr_pose must be > 0; got {self.lr_pose!r}")
        if not 0 < self.map_norm_momentum <= 1:
            raise AvatarError(f"HFMConfig.map_norm_momentum must be in (0, 1]; got {self.map_norm_momentum}")
        if not 0 <= self.warmup < 1:
            raise AvatarError(f"HFMConfig.warmup is a fraction of iters in [0, 1); got {self.warmup}")
        if not 0 <= self.ema < 1:
            raise AvatarError(f"HFMConfig.ema is a decay per step in [0, 1); got {self.ema}")

    @property
    def usage_fit_names(self) -> tuple:
        """The landmarks below a headset that the usage poses are fitted to (``usage_landmarks``):
        :data:`~geoface.avatar.head_pose.LOWER_RIGID_NAMES` or :data:`~geoface.avatar.head_pose.LOWER_STABLE_NAMES`."""
        from geoface.avatar.head_pose import LOWER_RIGID_NAMES, LOWER_STABLE_NAMES

        return LOWER_STABLE_NAMES if self.usage_landmarks == "stable" else LOWER_RIGID_NAMES

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where: str = "HFM config") -> "HFMConfig":
        from geoface.nn.config import config_from_dict

        from geoface.errors import ModelFolderError

        return config_from_dict(cls, d, where=where, error=ModelFolderError)
