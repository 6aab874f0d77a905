"""Errors raised by :mod:`geoface.splat` (subclasses of :class:`geoface.errors.GeofaceError`)."""
from __future__ import annotations

from geoface.nn.errors import CameraError, RenderError

__all__ = ["SplatError", "CameraError", "GaussianPlyError"]


class SplatError(RenderError):
    """Bad input to the Gaussian-splatting toolkit (shapes, files, fitting options).  Cameras and
    mesh renders (:mod:`geoface.camera`, :mod:`geoface.nn.mesh_render`) raise
    :class:`geoface.nn.errors.CameraError` / ``RenderError``, of which this is a sibling. The
    avatars built on it raise :class:`geoface.errors.AvatarError`."""


class GaussianPlyError(SplatError):
    """A PLY file that is not in the 3DGS layout."""
