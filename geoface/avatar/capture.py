"""What both avatars add to the capture folder (:mod:`geoface.capture`, re-exported here): the
headset's proxy mesh and the synthetic captures' tracking step.

Each avatar adds files of its own (:mod:`geoface.hfm.data`, :mod:`geoface.thgs.data`).
"""
from __future__ import annotations

import numpy as np

from geoface.errors import GeofaceError
from geoface.capture import (Capture, camera_from_json, camera_to_json, read_landmarks,  # noqa: F401  (re-exported)
                             stack_frames, write_camera, write_frame, write_head_poses, write_landmarks)
from geoface.landmarks import IBUG68_LOWER, IBUG68_NAMES, IBUG68_RIGID  # noqa: F401  (re-exported)
from geoface.rotations import euler_rotation  # noqa: F401  (re-exported)

__all__ = ["track_synthetic", "IBUG68_NAMES", "IBUG68_LOWER", "IBUG68_RIGID", "write_frame", "stack_frames",
           "camera_from_json", "camera_to_json", "read_landmarks", "euler_rotation", "headset_mesh", "Capture",
           "write_landmarks", "write_camera", "write_head_poses"]


def headset_mesh(y_split: float, front_z: float, width: float = 0.19, height: float = 0.075,
                 depth: float = 0.07):
    """A box-shaped headset (V, F) in front of the upper face: bottom edge at ``y_split``, front face
    at ``front_z + 0.02``."""
    x0, x1 = -width / 2, width / 2
    y0, y1 = y_split, y_split + height
    z1 = front_z + 0.02
    z0 = z1 - depth
    V = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    # vertex index = 4·ix + 2·iy + iz; outward, counter-clockwise faces
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (1, 5, 7, 3), (0, 2, 6, 4)]
    F = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return V, F


def track_synthetic(folders, landmarks: str | None, head: str, *, quiet: bool | None = None) -> str:
    """The avatars' ``synth --landmarks``: with ``tracked`` (the default for ``head`` ``"ict"``),
    each synthetic capture folder's landmarks and masks replaced in place by the tracker's
    (:func:`geoface.track.track_capture`), the renderer's kept as ``*_true``; ``oracle`` leaves
    the renderer's. Returns the tail of the verb's summary line saying which the folders hold."""
    if (landmarks or ("tracked" if head == "ict" else "oracle")) == "oracle":
        return "; landmarks and masks: the renderer's (oracle)"
    from geoface.track import track_capture

    try:
        found = [track_capture(d, d, keep_originals=True, overwrite=True, quiet=quiet).found for d in folders]
    except GeofaceError as e:
        raise GeofaceError(f"{e} (--landmarks oracle keeps the renderer's)") from e
    return (f"; landmarks and masks tracked by MediaPipe (a face on {sum(int(f.sum()) for f in found)} of "
            f"{sum(len(f) for f in found)} frames; the renderer's kept as *_true)")
