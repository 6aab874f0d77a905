"""What both avatars (:mod:`geoface.hfm`, :mod:`geoface.thgs`) share: captures made from a real
clip (:func:`capture_clip`, ``geoface capture``), the capture folder (frames, camera, landmarks), audio features, head pose from landmarks, kinematics and templates
(skinned heads), per-frame pose corrections, model folders, and the ICT-FaceKit person their
synthetic captures render.

Light on purpose: torch is imported only when a torch-backed name is first used.
"""
from __future__ import annotations

from geoface._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.avatar", {
    "audio_context": "audio", "audio_features": "audio", "envelope": "audio", "log_mel": "audio",
    "read_wav": "audio", "speech_like": "audio", "capture_clip": "clip", "write_overlay": "clip", "capture_head": "clip",
    "ClipCapture": "clip", "Capture": "geoface.capture", "IBUG68_LOWER": "geoface.landmarks", "IBUG68_NAMES": "geoface.landmarks", "IBUG68_RIGID": "geoface.landmarks",
    "camera_from_json": "capture", "camera_to_json": "capture", "euler_rotation": "capture",
    "headset_mesh": "capture", "read_landmarks": "capture", "stack_frames": "capture",
    "write_frame": "capture", "FrameCorrections": "corrections",
    "corrected_pose": "corrections", "LOWER_RIGID_NAMES": "head_pose", "LOWER_STABLE_NAMES": "head_pose",
    "STABLE_NAMES": "head_pose", "apply_lower_calibration": "head_pose",
    "calibrate_lower_poses": "head_pose", "calibration_scores": "head_pose",
    "canonical_landmarks": "head_pose", "expression_reach": "head_pose", "landmark_expressions": "head_pose",
    "landmarks_on_mesh": "head_pose", "poses_from_landmarks": "head_pose", "ray_offsets": "head_pose",
    "repivot": "head_pose", "rigidity_weights": "head_pose", "rodrigues": "head_pose",
    "rotation_vector": "head_pose", "solve_poses": "head_pose", "triangulate": "head_pose",
    "ICTPerson": "ict", "ICT_PARTS": "ict", "arkit_curves": "ict", "head_motion": "ict",
    "is_upper_blendshape": "ict", "axis_angle_to_matrix": "kinematics", "joint_transforms": "kinematics",
    "skin_points": "kinematics", "read_model_config": "model_dir", "read_model_dir": "model_dir",
    "write_model_dir": "model_dir", "SMPLX_SHAPE_DIM": "template", "Template": "template",
    "load_smplx": "template", "procedural_template": "template",
})
