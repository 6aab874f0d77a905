"""Deprecated: the two neural consumers that lived here are packages of their own since 0.3 —
:mod:`geoface.ddpm` (the text-guided DDPM of heads) and :mod:`geoface.texture` (the GDE/HFDR skin
textures). The old names still resolve, with a :class:`DeprecationWarning`.
"""
import warnings

from .._lazy import lazy_exports

_ddpm = ("DDPMConfig", "DiffusionRun", "train", "load_run", "sample", "to_geometry_images", "GImageDataset",
         "find_items", "DataStats", "make_text_encoder", "TextEncoder", "mesh_validity", "Validity", "TextEncoderError")
_texture = ("TextureTrainConfig", "TextureModel", "train_texture", "reconstruct_textures", "TextureReconstruction",
            "CameraSeesNothingError", "make_texture_dataset", "LearnError")
_get, __dir__, __all__ = lazy_exports("geoface.learn", {
    **{n: "geoface.ddpm" for n in _ddpm}, **{n: "geoface.texture" for n in _texture}, "CheckpointError": "geoface.errors"})


def __getattr__(name):
    value = _get(name)
    home = _get.homes[name]
    warnings.warn(f"geoface.learn.{name} is deprecated: import it from {home}", DeprecationWarning, stacklevel=2)
    return value
