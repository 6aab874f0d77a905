"""HFM-GS: half-face-mapping Gaussian avatars for real-time HMD removal (Wang et al., TVCG 2025).

A person is registered from a short unoccluded video; afterwards, each frame of a video in which
a headset hides the upper face is restored from the visible lower face alone:

1. **Latent** θ = E_img(lower-face crop): five stride-2 convolutions (128² → 4²) and one
   self-attention layer over the 16 cells, flattened to a 128-d code.
2. **Canonical Gaussians** from the registration head mesh (one per vertex), split by the
   plane y = y_t into an upper set U (y > y_t) and a lower set L.
3. **Lower face** (eq. 2): for i ∈ L, ΔX_i, ΔS_i, ΔR_i = MLP_X, MLP_S, MLP_R(γ(x_i), θ) with
   γ the NeRF frequency embedding of the canonical position.
4. **Gaussian mapping** (eq. 3–4): φ_i = MLP_gm(γ(x_i)) ∈ R^10 and W_gm = row-softmax(φ_U φ_Lᵀ),
   how much each upper Gaussian follows each lower one.
5. **Parameter mapping** (eq. 6–7): lower features f_L = MLP_pm(γ(x_L), p̂_L) of the lower
   deformations p_L = (ΔX, log ΔS, ΔR); upper features f_U = W_gm f_L; upper deformations
   (eq. 5/7) p_U = MLP_mapping(γ(x_U), f_U). p̂_L = p_L / RMS is each channel divided by its
   running RMS over training (``map_norm``, a buffer saved with the model; like batch norm's
   running statistics, without centring): the networks start at the identity, so p_L grows from
   0 to a few hundredths, and read raw it stayed a small part of MLP_pm's input next to the O(1)
   position embedding; on the synthetic head the upper face then hardly followed the lower one.
   The mapping reads p_L detached (``detach_lower``, default on): the upper-face loss then trains
   the mapping networks but not the lower face's. On the synthetic videos, detaching gained Full
   0.4 dB in the occluded region (five of six runs) and 0.2 dB on the whole face (six of six)
   over training the lower networks through the mapping. Detached, the encoder learns from the
   lower face alone; ``map_latent_grad`` lets the upper-face loss train θ through frozen copies of
   the eq.-2 networks (off: on two further heads it changed the occluded region by +0.05 and
   −0.47 dB). MLP_mapping reads f_U standardised per channel by its running mean and standard
   deviation (``feat_norm``, buffers saved with the model): f_U is mostly a constant (the average
   of MLP_pm over the key positions) and moves with the expression ~20× less than θ moves the
   eq.-2 networks' input (regression on the eyes' closing, synthetic head), so MLP_mapping
   learned the lids' closing in a smile too slowly to show it within training. MLP_mapping is
   three MLPs on the same input, one each for ΔX, log ΔS and ΔR (``mapping_heads=3``), as eq. 2
   decodes the lower face: one MLP for all ten outputs gave the upper face a third of the hidden
   units that the variant without the mapping spends on it, and on the synthetic head it fit the
   brows' raise and the lids' closing worse than that variant even on the training frames (mean
   squared error on the 12 strongest surprise / smile frames, data seed 1: 3.0 / 1.5 ·10⁻⁴
   against 2.0 / 1.1; with three heads 2.9 / 1.1). At the end of training both normalisations'
   statistics are recomputed as plain means over the registration frames with the final
   weights (:meth:`HFMModel.refit_statistics`).
6. **Global pose** (eq. 8): (ω, τ) = MLP_pose(θ), a rotation exp(ω) about the head centre and a
   translation applied to every Gaussian after the local deformation, then the head pose of the
   frame (X' = R (X − pivot) + pivot + t), so that the MLP learns the residual of that pose.
   Registration takes the head pose of each frame from ``head_poses.npz`` when the folder has
   one (a face tracker's), else fits it to the frame's landmarks (:mod:`geoface.splat.head_pose`:
   PnP of the landmarks that move little with expressions, placed on the canonical head through
   frame 0). Learning the pose only through the image loss stalls: on the procedural videos
   (yaw ±8°) training then stopped at an L1 loss near 0.05, against 0.007 for a still head. In
   use, the pose comes from ``head_poses.npz`` (a headset's own 6-DoF tracking, when the user has
   it in the camera's frame) or, as in the paper, from the lower-face image: MLP_head_pose(θ)
   (``image_pose``) predicts (ω, τ) of the whole head pose and is trained during registration on
   the registration poses (squared error, ``lambda_pose``; the encoder learns from it too, unless
   ``image_pose_detach``: then the pose MLP learns alone from the latent).
   ``pose_residual=False`` leaves MLP_pose out and keeps the pose read from the crop. Poses fitted
   to the usage video's lower landmarks are calibrated into the registration poses' frame by a
   linear model learned during registration (``pose_calibration``;
   :func:`geoface.splat.head_pose.calibrate_lower_poses`), and, with ``headset_pose``, moved by
   what the lower face's expressions do to where the headset's silhouette lies
   (:mod:`geoface.splat.headset_pose`).
7. **Correlation-weight sampling** (eq. 9–10): the mapping runs between 512 upper and 512 lower
   *key* Gaussians only — upper keys by farthest-point sampling of the canonical positions,
   lower keys 512 drawn without replacement with probability proportional to their correlation
   weight Σ_u W_gm[u, l] towards the upper keys (``lower_keys="sample"``, the default; ``"top"``
   takes the 512 largest, which lets an early, still uninformative W_gm lock the keys onto one
   region — on the synthetic head, the neck, away from the mouth that carries the expression) —
   and every upper Gaussian takes the inverse-distance average (W_dist, k nearest upper
   keys, rows sum to 1) of the keys' upper features f_U, which MLP_mapping turns into its
   deformation at its own position (``upsample="features"``); ``"params"`` averages the keys'
   deformations instead. Upper keys lie ~12 mm apart on the synthetic head, and averaging
   deformations moves a lid, the eye under it and the brow above it alike, so the eyes could not
   close in a smile. Cost O(512²) for the mapping plus one MLP per upper Gaussian (like the
   eq.-2 networks per lower one) instead of O(|U|·|L|). Keys are refreshed after every
   densification and every ``key_every`` steps.
8. **Composition** (eq. 1): X + ΔX, S·ΔS, R ⊗ ΔR; then the global pose.

**Gaussian segregation** (Algorithm 1 and eq. 11–12): density control where a split child that
crosses y_t by more than ``margin`` (an upper parent's child below y_t − m, a lower parent's
above y_t + m) is dropped, and ReLU boundary losses Σ_U ReLU(y_t − y) + Σ_L ReLU(y − y_t) (means
over each set) on the canonical positions keep the halves apart.

**Loss** (eq. 13): (1 − λ_rgb)·L1 + λ_rgb·D-SSIM + λ_vgg·L_vgg + λ_split·L_split with
λ_rgb = 0.4, λ_vgg = 0.1, λ_split = 0.01. L_vgg compares VGG-16 features (relu1_2, relu2_2,
relu3_3) and needs local weights (``vgg_weights``: a safetensors/torch file of torchvision's
``vgg16().features`` state dict, keys ``features.N.weight``); without them it is left out and
training says so.

**Training.** One frame per step, Adam. The first ``warmup`` (20%) of the steps train the
Gaussians alone (the networks start at the identity deformation); the networks then train at
``lr_nets`` = 2e-4 with Adam's usual ε. At 1e-3 (and the 3DGS ε = 1e-15 for everything) the
deformation MLPs lost most of their ReLU units within a few hundred steps and the encoder
collapsed θ to a near constant for some model seeds: the avatar then never followed an
expression (upper-face Gaussians moved by 1e-6 m across frames) and the ablation comparison
measured which seeds happened to escape. The saved model is the exponential moving average of
all weights (Gaussians and networks; ``ema`` = 0.99 per step, bias-corrected, :class:`WeightAverage`)
over the steps after density control stops. With one frame per step the weights never settle:
continuing two trained models (Full and the variant without the mapping) for 300 steps on the
synthetic head, checkpoints 25 steps apart scored 33.5–35.6 dB in the occluded region (SD 0.63),
so a model's score was mostly the luck of its last step, and so was every comparison between
variants; a moving average of the same steps (decay 0.98) scored 34.4–35.9 dB (SD 0.39), 0.6 dB
higher on average.

Ablations (``HFMConfig``): ``global_pose=False`` (no pose MLPs: without a pose file the head
stays in its canonical pose), ``gaussian_mapping=False`` (no
Gaussian & feature mapping: the upper face is deformed from θ by the lower face's networks of
eq. 2, one deformation field over the whole head; ``unmapped_upper="separate"`` gives it its own
MLP instead, a stronger baseline than the paper's ablation with more weights than the mapping's),
``feature_mapping=False`` (W_gm maps the lower deformations p_L themselves, no MLP_pm),
``sampling=False`` (the mapping over all Gaussians).

The code: :mod:`~geoface.splat.hfm_model` (configuration, ablations, the model),
:mod:`~geoface.splat.hfm_blocks` (its building blocks), :mod:`~geoface.splat.hfm_train`
(registration, saving and loading), :mod:`~geoface.splat.hfm_usage` (removal and evaluation);
this module gathers their public names.
"""
from __future__ import annotations

from geoface.nn.average import WeightAverage
from geoface.splat.hfm_blocks import (SegregationStrategy, boundary_loss, farthest_point_sampling,
                                      inverse_distance_weights, ImageEncoder)
from geoface.splat.hfm_model import ABLATIONS, HFMConfig, HFMModel, select_keys
from geoface.splat.hfm_train import VGGPerceptual, build_model, load_hfm, save_hfm, train_hfm
from geoface.splat.hfm_usage import evaluate_hmd, expression_coverage, expression_motion, hmd_metrics, remove_hmd

__all__ = ["HFMConfig", "HFMModel", "ImageEncoder", "SegregationStrategy", "WeightAverage", "select_keys",
           "inverse_distance_weights", "farthest_point_sampling", "boundary_loss", "VGGPerceptual",
           "expression_motion", "expression_coverage", "build_model", "train_hfm", "save_hfm", "load_hfm", "remove_hmd", "evaluate_hmd",
           "hmd_metrics", "ABLATIONS"]
