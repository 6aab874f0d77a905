"""Errors raised by :mod:`geoface.splat` (subclasses of :class:`geoface.errors.GeofaceError`)."""
from __future__ import annotations

from geoface.errors import CaptureError, CheckpointError
from geoface.nn.errors import CameraError, RenderError

__all__ = ["SplatError", "CameraError", "GaussianPlyError", "ModelFolderError"]


class SplatError(RenderError, CaptureError):
    """Bad input to the Gaussian-splatting toolkit (shapes, files, avatar options).  Cameras and
    mesh renders (:mod:`geoface.camera`, :mod:`geoface.nn.mesh_render`) raise
    :class:`geoface.nn.errors.CameraError` / ``RenderError``, of which this is a sibling; it is a
    :class:`geoface.errors.CaptureError` too (the avatars' capture problems)."""


class GaussianPlyError(SplatError):
    """A PLY file that is not in the 3DGS layout."""


class ModelFolderError(SplatError, CheckpointError):
    """A saved avatar model folder that cannot be read (a :class:`CheckpointError` too)."""
