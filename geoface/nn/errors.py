"""Errors of the shared building blocks (rooted at :class:`geoface.GeofaceError`; defined in
:mod:`geoface.errors`, where the camera, below every consumer, raises them too)."""
from __future__ import annotations

from geoface.errors import CameraError, NNError, RenderError

__all__ = ["NNError", "RenderError", "CameraError"]
