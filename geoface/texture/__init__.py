"""Ultra-high-resolution skin textures from a photo (the 4K-texture paper): the Normal&UV
predictor, the Global Distribution Extractor (GDE) with its UV hash encoding, the High-Frequency
Detail Refiner (HFDR) on full-resolution patches, their staged training, the synthetic skin data
they learn from, and the maps carried into a mesh's UV space. ``docs/textures.md`` is the guide.

Importing this package does not import torch; each name loads its module (and torch) when first
used.

>>> from geoface.texture import TextureModel, reconstruct_textures
>>> model = TextureModel.load("texmodel/")                          # doctest: +SKIP
>>> rec = reconstruct_textures(model, photo, landmarks=lm68)       # doctest: +SKIP
"""
from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.texture", {
    "TextureTrainConfig": "model", "TextureModel": "model", "train_texture": "model",
    "reconstruct_textures": "uv", "TextureReconstruction": "uv", "CameraSeesNothingError": "uv",
    "make_texture_dataset": "synth",
    "LearnError": "geoface.errors", "CheckpointError": "geoface.errors",
})
