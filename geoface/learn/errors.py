"""Errors of the neural add-ons (rooted at :class:`geoface.GeofaceError`)."""
from __future__ import annotations

from geoface.errors import CheckpointError, GeofaceError

__all__ = ["CheckpointError", "LearnError", "TextEncoderError"]


class TextEncoderError(GeofaceError):
    """A text encoder could not be built or loaded (bad name, missing local weights)."""


class LearnError(GeofaceError):
    """An invalid argument or input to a neural component (shapes, sizes, options)."""
