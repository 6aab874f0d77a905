"""Neural consumers of geometry images: the text-guided DDPM of heads and the GDE/HFDR skin
textures.  Importing this package does not import torch; each name loads its module (and
torch) when first used.

>>> from geoface.learn import load_run, sample
>>> run = load_run("run/")                       # doctest: +SKIP
>>> x = sample(run, "a smiling female", n=4)     # doctest: +SKIP
"""
from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.learn", {
    # the diffusion model of heads
    "DDPMConfig": "ddpm", "DiffusionRun": "ddpm", "train": "ddpm", "load_run": "ddpm", "sample": "ddpm",
    "to_geometry_images": "ddpm",
    "GImageDataset": "data", "find_items": "data", "DataStats": "data",
    "make_text_encoder": "text", "TextEncoder": "text",
    # how samples are judged
    "mesh_validity": "evaluate", "Validity": "evaluate",
    # skin textures (GDE/HFDR)
    "TextureTrainConfig": "texture", "TextureModel": "texture", "train_texture": "texture",
    "reconstruct_textures": "texture_uv", "TextureReconstruction": "texture_uv",
    "CameraSeesNothingError": "texture_uv",
    "make_texture_dataset": "skin_synth",
    "LearnError": "errors", "CheckpointError": "errors", "TextEncoderError": "errors",
})
