"""One exception hierarchy for geoface.

Every error that bad *input* can cause is a :class:`GeofaceError`; the CLI turns it
into one line on stderr and exit code 2.  Programming errors stay ordinary Python
exceptions.
"""

from __future__ import annotations


class GeofaceError(Exception):
    """Root of every error geoface raises for bad input or impossible requests."""


class MeshFormatError(GeofaceError):
    """A file could not be read or written as a mesh (missing, empty, corrupt, not a mesh)."""


class PointCloudError(MeshFormatError):
    """The file holds points and no triangles: ``geoface.repair.surface_from_points`` (or
    ``convert`` / ``repair``, which call it) makes a surface of them."""


class InvalidMeshError(GeofaceError):
    """Mesh arrays are malformed: wrong shapes, NaN/inf coordinates, indices out of range."""


class MeshTopologyError(GeofaceError):
    """A mesh does not have (and could not be given) the topology an algorithm needs."""


class ParameterizationError(GeofaceError):
    """A parameterization (Ricci flow, optimal transport) failed or was given bad input."""


class InvalidGeometryImageError(GeofaceError):
    """A geometry image or its metadata is malformed."""


class CheckpointError(GeofaceError):
    """A model or training-run folder (config, weights, state) is missing, truncated or
    inconsistent, or a field of its config has the wrong type or range."""


class AvatarError(GeofaceError):
    """Bad input to the avatars (HFM-GS, THGS and what they share): their options, their model
    folders, what drives them; a capture's problems are its subclass :class:`CaptureError`."""


class CaptureError(AvatarError):
    """A capture folder (frames, landmarks, camera, poses, ...) or a clip that cannot be read or made
    (:mod:`geoface.capture`)."""


class ModelFolderError(AvatarError, CheckpointError):
    """A saved avatar model folder that cannot be read (a :class:`CheckpointError` too)."""


class TextEncoderError(GeofaceError):
    """A text encoder could not be built or loaded (bad name, missing local weights)."""


class LearnError(GeofaceError):
    """An invalid argument or input to a neural component (shapes, sizes, options)."""


class MissingDependencyError(GeofaceError, ImportError):
    """An optional dependency needed by the requested feature is not installed."""


class GeofaceWarning(UserWarning):
    """Something was changed or could not be kept (e.g. a format that cannot store UVs)."""


class NNError(GeofaceError):
    """An invalid argument or input to a shared neural building block (shapes, sizes, options)."""


class RenderError(NNError):
    """Bad input to a renderer: meshes, colours, textures, shading, cameras."""


class CameraError(RenderError):
    """A camera that cannot be built (degenerate look-at, non-positive focal length...)."""
