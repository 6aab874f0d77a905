"""Gaussian splatting on CPU (and gsplat on CUDA): cameras, Gaussians, a differentiable rasterizer.

Light on purpose: torch is imported only when a torch-backed name is first used.

>>> from geoface.splat import look_at, Gaussians, rasterize   # doctest: +SKIP
"""
from __future__ import annotations

from geoface._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.splat", {
    "Camera": "geoface.camera", "look_at": "geoface.camera", "orbit": "geoface.camera",
    "Gaussians": "gaussians", "GaussianTensors": "gaussians", "eval_sh": "gaussians",
    "covariance": "gaussians",
    "save_ply": "ply", "load_ply": "ply",
    "rasterize": "rasterizer", "rasterize_reference": "rasterizer",
    "DensityConfig": "density", "DensityStrategy": "density", "make_optimizer": "density",
    "render_mesh": "geoface.nn.mesh_render", "rasterize_mesh": "geoface.nn.mesh_render", "MeshRender": "geoface.nn.mesh_render",
    "FitConfig": "fit", "FitResult": "fit", "fit_mesh": "fit",
    "SplatError": "errors", "CameraError": "errors", "GaussianPlyError": "errors",
})
