"""HFM-GS: removing a head-mounted display from video with a Gaussian head avatar.

A registration video (no headset) trains the avatar (:func:`train_hfm`): canonical Gaussians
on the head mesh, an image encoder of the lower face, Gaussian feature mapping to the upper face
and the segregation strategy that keeps the two apart. A usage video (headset on) drives it
(:func:`remove_hmd`); :func:`evaluate_hmd` scores the occluded region against the ground truth.
``docs/hmd.md`` is the guide, ``docs/papers.md`` maps the paper to these functions.

Light on purpose: torch is imported only when a torch-backed name is first used.
"""
from __future__ import annotations

from geoface._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.hfm", {
    "align_poses": "align", "HMDVideo": "data", "LOWER_FACE_LANDMARKS": "data", "UPPER_EXPRESSIONS": "data",
    "crop_lower_face": "data", "expressions_from_drivers": "data", "frame_input": "data",
    "load_video": "data", "lower_face_box": "data", "make_synthetic_hmd": "data",
    "fit_headset": "headset_pose", "headset_centroids": "headset_pose", "headset_components": "headset_pose",
    "headset_poses": "headset_pose", "refine_with_headset": "headset_pose",
    "ABLATIONS": "config", "HFMConfig": "config", "HFMModel": "model", "select_keys": "model",
    "ImageEncoder": "blocks", "SegregationStrategy": "blocks", "boundary_loss": "blocks",
    "farthest_point_sampling": "blocks", "inverse_distance_weights": "blocks",
    "VGGPerceptual": "train", "build_model": "train", "load_hfm": "io", "save_hfm": "io", "train_hfm": "train",
    "evaluate_hmd": "usage", "expression_coverage": "usage", "expression_motion": "usage", "hmd_metrics": "usage",
    "remove_hmd": "usage", "make_ict_hmd": "ict", "WeightAverage": "geoface.nn.average",
})
