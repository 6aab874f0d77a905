"""UV bake, inpainting and image-to-UV projection.

- :func:`bake_gimage` / :func:`bake_texture`: closest-point transfer of colours (vertex colours
  or UV + texture) and object-space normals from a high-resolution scan onto a geometry image
  or a target mesh's UV texture.
- :func:`inpaint`: fill empty texels (push–pull, biharmonic, Telea; seam dilation); valid
  texels are never changed.
- :func:`project_views`: blend photos from pinhole cameras (OpenCV convention) into a UV
  texture with z-buffer visibility and view-angle weights.

>>> import numpy as np
>>> from geoface.uvmap import inpaint
>>> img = np.zeros((4, 4, 3)); m = np.zeros((4, 4), bool); m[0, 0] = True; img[0, 0] = 1.0
>>> bool(np.allclose(inpaint(img, m), 1.0))
True
"""

from .bake import BakeResult, SurfaceQuery, bake_gimage, bake_texture, closest_points, sample_source, texel_geometry
from .inpaint import dilate_valid, inpaint, push_pull
from .project import Camera, ProjectionResult, depth_buffer, project_views

__all__ = [
    "BakeResult", "SurfaceQuery", "bake_gimage", "bake_texture", "closest_points", "sample_source", "texel_geometry",
    "dilate_valid", "inpaint", "push_pull",
    "Camera", "ProjectionResult", "depth_buffer", "project_views",
]
