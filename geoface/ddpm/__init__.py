"""The text-guided DDPM of heads as geometry images ("Text-Guided 3D Head Synthesis Using
Geometry Images"): the dataset reader, the UNet and its training and sampling, the text
encoders, and how samples are judged (validity, renders). ``docs/ddpm.md`` is the guide.

Importing this package does not import torch; each name loads its module (and torch) when first
used.

>>> from geoface.ddpm import load_run, sample
>>> run = load_run("run/")                       # doctest: +SKIP
>>> x = sample(run, "a smiling female", n=4)     # doctest: +SKIP
"""
from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.ddpm", {
    "DDPMConfig": "model", "DiffusionRun": "model", "train": "model", "load_run": "model", "sample": "model",
    "to_geometry_images": "model",
    "GImageDataset": "data", "find_items": "data", "DataStats": "data",
    "make_text_encoder": "text", "TextEncoder": "text",
    # how samples are judged
    "mesh_validity": "evaluate", "Validity": "evaluate",
    "CheckpointError": "geoface.errors", "TextEncoderError": "geoface.errors",
})
