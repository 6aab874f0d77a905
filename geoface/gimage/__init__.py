"""Geometry images: rasterize position / normal / texture of a parameterized disk into N×N
16-bit images, and turn images back into meshes.

>>> from geoface.synth import square_grid
>>> from geoface.gimage import geometry_image, reconstruct
>>> V, F = square_grid(5)
>>> gi = geometry_image(V, F, V[:, :2], 8)
>>> gi.image.shape, bool(gi.mask.all())
((6, 8, 8), True)
"""

from .image import FORMAT_VERSION, MODALITIES, GeometryImage, geometry_image, gimage_from_samples, load_gimage, save_gimage
from .raster import interpolate, rasterize_faces, sample_texture
from .reconstruct import pixel_uv, reconstruct, save_reconstruction

__all__ = [
    "FORMAT_VERSION", "MODALITIES", "GeometryImage", "geometry_image", "gimage_from_samples", "load_gimage", "save_gimage",
    "interpolate", "rasterize_faces", "sample_texture", "pixel_uv", "reconstruct", "save_reconstruction",
]
