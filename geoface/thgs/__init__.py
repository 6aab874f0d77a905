"""THGS: a talking human avatar of Gaussians driven by speech.

Linear blend skinning with a voxel skinning grid, learnable expression blendshapes and the
spatial audio attention module (:class:`THGSModel`), trained on a talking capture
(:func:`train_thgs`) and animated from audio alone (:func:`animate`). ``docs/thgs.md`` is the
guide, ``docs/papers.md`` maps the paper to these functions.

Light on purpose: torch is imported only when a torch-backed name is first used.
"""
from __future__ import annotations

from geoface._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.thgs", {
    "TalkingData": "data", "landmark_loss": "data", "load_talking": "data", "load_tracked": "data", "fit_head_poses": "data",
    "make_synthetic_talking": "data", "mouth_landmark_targets": "data", "speech_like": "data",
    "corrected_poses": "eval", "evaluate_thgs": "eval", "head_pose_errors": "eval", "lip_gaps": "eval",
    "lip_points": "eval", "mouth_openness": "eval", "true_lip_gaps_px": "eval", "JOINT_NAMES": "ict",
    "ict_template": "ict", "is_mouth_blendshape": "ict", "make_ict_talking": "ict", "perturb_capture": "ict",
    "AudioArticulation": "blocks", "ExpressionBlendshapes": "blocks", "ExternalAttention": "blocks",
    "SpatialAudioAttention": "blocks", "THGSConfig": "model", "THGSModel": "model", "VoxelSkinning": "blocks",
    "animate": "inference", "lbs": "blocks", "load_thgs": "inference", "mouth_gaussians": "blocks",
    "render_frames": "inference", "save_thgs": "inference", "train_thgs": "train", "posed_points": "prefit",
    "prefit_articulation": "prefit", "prefit_training": "prefit",
    "train_heldout_split": "train",
})
