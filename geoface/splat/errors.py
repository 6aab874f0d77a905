"""Errors raised by :mod:`geoface.splat` (subclasses of :class:`geoface.errors.GeofaceError`)."""
from __future__ import annotations

from geoface.errors import CheckpointError, GeofaceError


class SplatError(GeofaceError):
    """Bad input to the Gaussian-splatting toolkit (shapes, cameras, files)."""


class CameraError(SplatError):
    """A camera that cannot be built (degenerate look-at, non-positive focal length...)."""


class GaussianPlyError(SplatError):
    """A PLY file that is not in the 3DGS layout."""


class ModelFolderError(SplatError, CheckpointError):
    """A saved avatar model folder that cannot be read (a :class:`CheckpointError` too)."""
