"""Driving a trained avatar (HFM-GS or THGS) frame by frame: its Gaussians per frame for the web
viewer, turntables and 3DGS PLY export (:func:`avatar_drive`, :func:`export_frames`).
"""
from __future__ import annotations

from geoface._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.drive", {
    "AvatarDrive": "avatars", "avatar_drive": "avatars", "avatar_kind": "avatars",
    "export_frames": "avatars", "parse_frames": "avatars", "splat_turntable": "avatars",
})
