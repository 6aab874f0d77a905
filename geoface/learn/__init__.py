"""Neural consumers of geometry images. Importing this package does not import torch.

Submodules (each imports torch itself): :mod:`geoface.learn.text` (text encoders),
:mod:`geoface.learn.errors` (``CheckpointError``, ``TextEncoderError``; torch-free).
"""
