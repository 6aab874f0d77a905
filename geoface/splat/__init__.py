"""Gaussian splatting on CPU (and gsplat on CUDA): cameras, Gaussians, a differentiable rasterizer.

Light on purpose: torch is imported only when a torch-backed name is first used.

>>> from geoface.splat import look_at, Gaussians, rasterize   # doctest: +SKIP
"""
from __future__ import annotations

import importlib

_NAMES = {
    "Camera": "geoface.camera", "look_at": "geoface.camera", "orbit": "geoface.camera",
    "Gaussians": "gaussians", "GaussianTensors": "gaussians", "eval_sh": "gaussians",
    "covariance": "gaussians",
    "save_ply": "ply", "load_ply": "ply",
    "rasterize": "rasterizer", "rasterize_reference": "rasterizer",
    "DensityConfig": "density", "DensityStrategy": "density", "make_optimizer": "density",
    "render_mesh": "geoface.nn.mesh_render", "rasterize_mesh": "geoface.nn.mesh_render", "MeshRender": "geoface.nn.mesh_render",
    "FitConfig": "fit", "FitResult": "fit", "fit_mesh": "fit",
    "SplatError": "errors", "CameraError": "errors", "GaussianPlyError": "errors",
}
__all__ = sorted(_NAMES)


def __getattr__(name):
    if name in _NAMES:
        mod = _NAMES[name]
        return getattr(importlib.import_module(mod if "." in mod else f"geoface.splat.{mod}"), name)
    raise AttributeError(f"module 'geoface.splat' has no attribute {name!r}")
