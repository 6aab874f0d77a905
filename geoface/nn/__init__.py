"""Pieces shared by the neural consumers (:mod:`geoface.ddpm`, :mod:`geoface.texture`, :mod:`geoface.splat`), so that
neither imports the other:

* :mod:`geoface.nn.hashenc` — multiresolution hash encodings (dense, 2D UV, tri-plane);
* :mod:`geoface.nn.losses` — SSIM / D-SSIM and the Laplacian loss;
* :mod:`geoface.camera` — pinhole cameras (OpenCV convention), ``look_at``, ``orbit``;
* :mod:`geoface.nn.mesh_render` — ground-truth renders of coloured or textured meshes (numpy);
* :mod:`geoface.nn.config` — saved configurations read through one validated path;
* :mod:`geoface.nn.errors` — ``NNError``, ``RenderError``, ``CameraError``.

Only ``hashenc`` and ``losses`` need torch; it is imported by those modules alone, when one
of their names is first used.
"""
from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.nn", {
    "Camera": "geoface.camera", "look_at": "geoface.camera", "orbit": "geoface.camera",
    "HashEncoding": "hashenc", "TriPlaneHashEncoding": "hashenc", "hash_encode": "hashenc",
    "ssim": "losses", "dssim": "losses", "laplacian_loss": "losses",
    "render_mesh": "mesh_render", "rasterize_mesh": "mesh_render", "MeshRender": "mesh_render",
    "WeightAverage": "average", "config_from_dict": "config", "train_device": "device",
    "NNError": "errors", "RenderError": "errors", "CameraError": "errors",
})
