"""Optional gsplat (CUDA) backend behind :func:`geoface.splat.rasterizer.rasterize` (lazy import)."""
from __future__ import annotations

from geoface.errors import MissingDependencyError


def gsplat_available() -> bool:
    try:
        import gsplat  # noqa: F401
        import torch
        return torch.cuda.is_available()
    except ImportError:
        return False


def rasterize_gsplat(gaussians, camera, background=None, near=0.01, return_info=False):
    """Same interface as :func:`rasterize`; rgb [H,W,3], alpha [H,W], depth [H,W] (expected).

    With ``return_info`` a 4th value: ``"means2d"`` is gsplat's own [1, N, 2] pixel-space tensor
    (unpacked; the one in the graph, so ``retain_grad`` works on it — read its grad with
    ``.reshape(-1, 2)``), ``"radii"`` [N] (max over axes for gsplat versions with per-axis radii).
    """
    try:
        from gsplat import rasterization
    except ImportError as e:
        raise MissingDependencyError("backend 'gsplat' needs gsplat: pip install gsplat") from e
    import torch
    dev, dt = gaussians.means.device, gaussians.means.dtype
    view = torch.eye(4, device=dev, dtype=dt)
    view[:3, :3] = torch.as_tensor(camera.R, device=dev, dtype=dt)
    view[:3, 3] = torch.as_tensor(camera.t, device=dev, dtype=dt)
    K = torch.as_tensor(camera.K, device=dev, dtype=dt)
    q = gaussians.quats / gaussians.quats.norm(dim=-1, keepdim=True)
    colors, deg = gaussians.colors, None
    if gaussians.is_sh:
        deg = gaussians.sh_degree
    bg = None if background is None else torch.as_tensor(background, device=dev, dtype=dt)[None]
    extra = {"packed": False} if return_info else {}
    img, alpha, meta = rasterization(gaussians.means, q, gaussians.log_scales.exp(),
                                     gaussians.opacities(), colors, view[None], K[None], camera.width,
                                     camera.height, near_plane=near, sh_degree=deg,
                                     render_mode="RGB+ED", backgrounds=bg, eps2d=0.3, **extra)
    out = img[0, ..., :3], alpha[0, ..., 0], img[0, ..., 3]
    if not return_info:
        return out
    radii = meta["radii"][0]
    if radii.ndim == 2:  # gsplat >= 1.5: per-axis radii [N, 2]
        radii = radii.max(-1).values
    info = {"means2d": meta["means2d"], "radii": radii.to(torch.int64), "width": camera.width,
            "height": camera.height}
    return (*out, info)
