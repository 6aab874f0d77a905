"""Skin maps from one photo, in the photo's frame and in a mesh's UV space: what
``geoface texture reconstruct`` does, as one library call (:func:`reconstruct_textures`).

The network (:func:`geoface.texture.model.reconstruct`) gives albedo, micro-normal and specular
maps aligned with the photo. With a mesh and the camera that took the photo, each map is
projected into the mesh's UV space (:func:`geoface.uvmap.project_views`) and the texels no
camera ray sees are filled by push-pull (:func:`geoface.uvmap.inpaint`). With 2D landmarks
instead, the ICT-FaceKit head and its camera are first fitted to them
(:func:`geoface.synth.ict_fit.fit_landmarks`); the landmarks may come from MediaPipe
(``landmarks="track"``), so that a photo alone is enough.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["TextureReconstruction", "reconstruct_textures", "MAP_CHANNELS", "CameraSeesNothingError"]


class CameraSeesNothingError(GeofaceError):
    """The camera (given, or fitted to the landmarks) sees no texel of the mesh: the camera or
    the landmarks belong to another photo or another frame convention."""

#: the maps and their channel counts
MAP_CHANNELS = {"albedo": 3, "micronormal": 3, "specular": 1}


@dataclass(frozen=True)
class TextureReconstruction:
    """``maps``: name -> (H, W, C) float in [0, 1] in the photo's frame (albedo, micronormal,
    specular, and the network's uv and normal inputs); ``uv_maps``: name -> (T, T, C) in the
    mesh's UV space (empty without a mesh); ``coverage``: the fraction of texels the camera sees;
    ``fit``: the landmark fit (``rms_px``, ``focal``, ``K``, ``R``, ``t``) when landmarks were
    given."""

    maps: dict
    uv_maps: dict = field(default_factory=dict)
    coverage: float | None = None
    mesh: object = None
    camera: object = None
    fit: object = None


def reconstruct_textures(model, photo: np.ndarray, *, mesh=None, camera=None, landmarks=None, focal: float | None = None,
                         uv_size: int = 1024, k: int | None = None, refine: bool = True) -> TextureReconstruction:
    """Skin maps of ``photo`` ((H, W, 3) float in [0, 1]) by ``model`` (a trained
    :class:`geoface.texture.model.TextureModel`), and, given ``mesh`` (a :class:`geoface.mesh.io.Mesh`
    with UVs) and ``camera`` (:class:`geoface.camera.Camera`) or ``landmarks`` ((68, 2) pixels,
    iBUG order, or ``"track"``: found in the photo by MediaPipe, :mod:`geoface.track`), the same
    maps in UV space at ``uv_size``². ``focal`` (pixels) fixes the landmark fit's focal length
    instead of fitting it."""
    from .model import reconstruct

    photo = np.asarray(photo)
    if photo.ndim != 3 or photo.shape[2] != 3:
        raise GeofaceError(f"photo must be (H, W, 3); got {photo.shape}")
    if (mesh is None) != (camera is None) and landmarks is None:
        raise GeofaceError("a mesh and its camera go together (the camera that took the photo of that mesh)")
    if landmarks is not None and mesh is not None:
        raise GeofaceError("landmarks fit the ICT head and its camera to the photo; they replace a mesh and camera")
    fit = None
    if isinstance(landmarks, str):
        if landmarks != "track":
            raise GeofaceError(f"landmarks must be (68, 2) points or 'track'; got {landmarks!r}")
        from geoface.track import track_frames

        landmarks = track_frames([photo], masks=False, video=False, quiet=True).landmarks[0]
    if landmarks is not None:
        from geoface.camera import Camera
        from geoface.mesh.io import Mesh
        from geoface.synth.ict import load_ict_model
        from geoface.synth.ict_fit import fit_landmarks

        H, W = photo.shape[:2]
        ict = load_ict_model()
        fit = fit_landmarks(ict, np.asarray(landmarks, np.float64), (W, H), focal=focal)
        head = fit.head(ict)
        mesh = Mesh(head.V, head.F, UV=head.UV, FUV=head.FUV)
        camera = Camera.from_K(fit.K, fit.R, fit.t, W, H)
    if mesh is not None and mesh.UV is None:
        raise GeofaceError("the mesh has no UVs to project the maps into")
    maps = reconstruct(model, photo, k=k, refine=refine)
    if mesh is None:
        return TextureReconstruction(maps=maps)
    from geoface.uvmap.inpaint import inpaint
    from geoface.uvmap.project import project_views

    uv_maps, seen = {}, None
    for name, c in MAP_CHANNELS.items():
        img = maps[name] if c == 3 else np.repeat(maps[name], 3, 2)
        res = project_views(mesh, [img.astype(np.float64)], [camera], size=uv_size)
        seen = res.weight > 0
        if not seen.any():
            raise CameraSeesNothingError("the camera sees none of the mesh")
        tex = inpaint(res.texture, seen)
        uv_maps[name] = tex if c == 3 else tex[:, :, :1]
    return TextureReconstruction(maps=maps, uv_maps=uv_maps, coverage=float(seen.mean()), mesh=mesh, camera=camera, fit=fit)
