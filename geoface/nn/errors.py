"""Errors of the shared building blocks (rooted at :class:`geoface.GeofaceError`)."""
from __future__ import annotations

from geoface.errors import GeofaceError

__all__ = ["NNError", "RenderError", "CameraError"]


class NNError(GeofaceError):
    """An invalid argument or input to a shared building block (shapes, sizes, options)."""


class RenderError(NNError):
    """Bad input to a renderer: meshes, colours, textures, shading, cameras."""


class CameraError(RenderError):
    """A camera that cannot be built (degenerate look-at, non-positive focal length...)."""
