"""The 68-point face landmark convention (iBUG 300-W / Multi-PIE; dlib, face_alignment, OpenFace
order) by name, and the subsets the avatars use: what trackers give (:mod:`geoface.track`), what
the ICT-FaceKit model marks, what captures store (:mod:`geoface.avatar.capture`)."""
from __future__ import annotations

__all__ = ["IBUG68_NAMES", "IBUG68_LOWER", "IBUG68_RIGID"]



def _ibug68_names() -> tuple:
    names = ([f"jaw_{i:02d}" for i in range(17)] + [f"brow_right_{i}" for i in range(5)]
             + [f"brow_left_{i}" for i in range(5)] + [f"nose_bridge_{i}" for i in range(4)]
             + [f"nose_base_{i}" for i in range(5)] + [f"eye_right_{i}" for i in range(6)]
             + [f"eye_left_{i}" for i in range(6)] + [f"lips_outer_{i:02d}" for i in range(12)]
             + [f"lips_inner_{i}" for i in range(8)])
    # the four the lower-face crop reads (the subject's left is the image right in a frontal view)
    names[8], names[30], names[48], names[54] = "chin", "nose_tip", "mouth_right", "mouth_left"
    return tuple(names)


#: names of the 68 iBUG / Multi-PIE points (dlib, face_alignment, OpenFace order): a
#: ``landmarks.json`` whose points are [T, 68, 2] may leave out ``names`` and gets these
IBUG68_NAMES = _ibug68_names()


#: indices of the 68 below a headset: jaw line, nose base (with its tip), lips
IBUG68_LOWER = tuple(range(0, 17)) + (30, 31, 32, 33, 34, 35) + tuple(range(48, 68))


#: indices of the 68 that move little with expressions (head-pose fitting): upper jaw line, nose,
#: eye corners
IBUG68_RIGID = (0, 1, 2, 14, 15, 16, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45)
