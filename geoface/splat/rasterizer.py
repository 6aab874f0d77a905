"""Differentiable Gaussian rasterizer on CPU (vectorised torch), with a slow reference.

Pipeline (3DGS, Kerbl et al. 2023):
  1. world → camera; cull Gaussians with z <= near.
  2. EWA: Σ2d = J W Σ Wᵀ Jᵀ + 0.3·I (the 0.3-pixel² low-pass), J the projection Jacobian.
  3. radius r = ceil(3·sqrt(λmax(Σ2d))); a Gaussian touches the pixels of its square
     [u−r, u+r]×[v−r, v+r] only (in both the tiled path and the reference, so they agree).
  4. tile binning: (tile, Gaussian) pairs built with repeat_interleave, sorted by
     (tile, depth) with one argsort.
  5. per tile: front-to-back compositing over depth-sorted chunks of ``chunk`` Gaussians,
     α = min(0.99, o·exp(−½ dᵀ Σ2d⁻¹ d)), α < 1/255 skipped, a Gaussian is used only while
     T·(1−α) ≥ 1e-4 (early termination), C = Σ T_i α_i c_i + T_final · background.
Complexity: O(P + Σ_tiles n_tile · tile²) work; memory O(tile² · chunk) per step. The Python
loop runs over tiles and chunks, never over pixels or Gaussians.
Outputs: rgb [H, W, 3], alpha [H, W] = 1 − T_final, depth [H, W] = Σ T_i α_i z_i / alpha
(0 where alpha = 0).
"""
from __future__ import annotations

import math

import torch

from geoface.splat.camera import Camera
from geoface.splat.errors import SplatError

LOWPASS = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4


def project_gaussians(means, covs, camera: Camera, near=0.01):
    """EWA projection. means [N,3], covs [N,3,3] → uv [N,2], depth [N], conic [N,2,2],
    radius [N] (int, 0 = culled)."""
    W = torch.as_tensor(camera.R, dtype=means.dtype)
    Xc = camera.world_to_camera(means)  # [N, 3]
    x, y, z = Xc.unbind(-1)
    valid = z > near
    zs = torch.where(valid, z, torch.ones_like(z))
    fx, fy = camera.fx, camera.fy
    uv = torch.stack([fx * x / zs + camera.cx, fy * y / zs + camera.cy], -1)
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * x / zs**2, zero, fy / zs, -fy * y / zs**2], -1).reshape(-1, 2, 3)
    M = J @ W  # [N, 2, 3]
    cov2 = M @ covs @ M.transpose(-1, -2) + LOWPASS * torch.eye(2, dtype=means.dtype)
    a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
    det = a * c - b * b
    conic = torch.stack([c, -b, -b, a], -1).reshape(-1, 2, 2) / det[:, None, None]
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.1))
        radius = torch.ceil(3 * torch.sqrt(lam)).to(torch.int64)
        radius = torch.where(valid & (det > 0), radius, torch.zeros_like(radius))
    return uv, z, conic, radius


def _alpha(pix, uv, conic, opac, radius):
    """pix [P,2], per-Gaussian uv [G,2], conic [G,2,2], opac [G], radius [G] → α [P,G]."""
    d = pix[:, None, :] - uv[None]  # [P, G, 2]
    power = -0.5 * (conic[None, :, 0, 0] * d[..., 0] ** 2 + conic[None, :, 1, 1] * d[..., 1] ** 2
                    + 2 * conic[None, :, 0, 1] * d[..., 0] * d[..., 1])
    alpha = torch.clamp_max(opac[None] * torch.exp(power), ALPHA_MAX)
    with torch.no_grad():
        r = radius.to(pix.dtype)[None]
        keep = (d[..., 0].abs() <= r) & (d[..., 1].abs() <= r) & (alpha >= ALPHA_MIN) & (power <= 0)
    return torch.where(keep, alpha, torch.zeros_like(alpha))


def _pixels(x0, x1, y0, y1, dtype):
    ys, xs = torch.meshgrid(torch.arange(y0, y1, dtype=dtype), torch.arange(x0, x1, dtype=dtype),
                            indexing="ij")
    return torch.stack([xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5], -1)


def _prepare(gaussians, camera, near):
    if not isinstance(camera, Camera):
        raise SplatError(f"camera must be a geoface.splat.camera.Camera; got {type(camera).__name__}")
    uv, z, conic, radius = project_gaussians(gaussians.means, gaussians.covariances(), camera, near)
    colors = gaussians.rgb(camera.center)
    return uv, z, conic, radius, gaussians.opacities(), colors


def _finish(C, D, T, background, H, W):
    alpha = 1 - T
    rgb = C
    if background is not None:
        bg = torch.as_tensor(background, dtype=C.dtype)
        rgb = C + T[:, None] * bg
    depth = torch.where(alpha > 0, D / torch.where(alpha > 0, alpha, torch.ones_like(alpha)),
                        torch.zeros_like(D))
    return rgb.reshape(H, W, 3), alpha.reshape(H, W), depth.reshape(H, W)


def _composite(alpha, T0, colors, z):
    """alpha [P,G] (depth order), T0 [P] → (C [P,3], D [P], T [P]) with early termination."""
    incl = T0[:, None] * torch.cumprod(1 - alpha, 1)  # T after each Gaussian
    with torch.no_grad():
        used = incl >= T_MIN
    a = torch.where(used, alpha, torch.zeros_like(alpha))
    Tin = T0[:, None] * torch.cumprod(torch.cat([torch.ones_like(a[:, :1]), 1 - a[:, :-1]], 1), 1)
    w = Tin * a
    return w @ colors, w @ z, Tin[:, -1] * (1 - a[:, -1])


def rasterize_reference(gaussians, camera: Camera, background=None, near=0.01):
    """Slow, obvious rasterizer: all Gaussians × all pixels, one global depth sort."""
    uv, z, conic, radius, opac, colors = _prepare(gaussians, camera, near)
    H, W = camera.height, camera.width
    live = torch.nonzero(radius > 0).reshape(-1)
    live = live[torch.argsort(z[live].detach(), stable=True)]
    pix = _pixels(0, W, 0, H, uv.dtype)
    if len(live) == 0:
        T = torch.ones(H * W, dtype=uv.dtype)
        return _finish(torch.zeros(H * W, 3, dtype=uv.dtype), torch.zeros(H * W, dtype=uv.dtype), T, background, H, W)
    alpha = _alpha(pix, uv[live], conic[live], opac[live], radius[live])
    C, D, T = _composite(alpha, torch.ones(H * W, dtype=uv.dtype), colors[live], z[live])
    return _finish(C, D, T, background, H, W)


def _bin(uv, radius, z, W, H, tile):
    """(tile id, Gaussian id) pairs sorted by tile then depth; returns ids, tile offsets."""
    tx, ty = math.ceil(W / tile), math.ceil(H / tile)
    u, v = uv.detach()[:, 0], uv.detach()[:, 1]
    r = radius.to(u.dtype)
    x0 = torch.clamp(torch.floor((u - r) / tile), 0, tx).to(torch.int64)
    x1 = torch.clamp(torch.floor((u + r) / tile), -1, tx - 1).to(torch.int64)
    y0 = torch.clamp(torch.floor((v - r) / tile), 0, ty).to(torch.int64)
    y1 = torch.clamp(torch.floor((v + r) / tile), -1, ty - 1).to(torch.int64)
    nx, ny = torch.clamp_min(x1 - x0 + 1, 0), torch.clamp_min(y1 - y0 + 1, 0)
    cnt = torch.where(radius > 0, nx * ny, torch.zeros_like(nx))
    gid = torch.repeat_interleave(torch.arange(len(uv)), cnt)
    start = torch.cumsum(cnt, 0) - cnt
    k = torch.arange(len(gid)) - start[gid]
    tid = (y0[gid] + k // nx[gid]) * tx + x0[gid] + k % nx[gid]
    rank = torch.empty_like(gid)
    order_z = torch.argsort(z.detach(), stable=True)
    rank_all = torch.empty(len(uv), dtype=torch.int64)
    rank_all[order_z] = torch.arange(len(uv))
    rank = rank_all[gid]
    order = torch.argsort(tid * len(uv) + rank)
    counts = torch.bincount(tid, minlength=tx * ty)
    return gid[order], torch.cumsum(counts, 0) - counts, counts, tx, ty


def rasterize(gaussians, camera: Camera, background=None, tile: int = 16, chunk: int = 256,
              near: float = 0.01, backend: str = "auto"):
    """Render ``gaussians`` seen by ``camera`` → (rgb [H,W,3], alpha [H,W], depth [H,W]).

    ``backend``: "torch" (this CPU path), "gsplat" (CUDA; needs gsplat), or "auto" (gsplat
    when importable and the tensors live on CUDA, else torch). Differentiable with respect to
    every Gaussian parameter through autograd.
    """
    if backend not in ("auto", "torch", "gsplat"):
        raise SplatError(f"backend must be 'auto', 'torch' or 'gsplat'; got {backend!r}")
    if tile < 1 or chunk < 1:
        raise SplatError(f"tile and chunk must be >= 1; got tile={tile}, chunk={chunk}")
    if backend != "torch" and gaussians.means.is_cuda:
        from geoface.splat._gsplat import rasterize_gsplat, gsplat_available
        if backend == "gsplat" or gsplat_available():
            return rasterize_gsplat(gaussians, camera, background, near)
    elif backend == "gsplat":
        raise SplatError("backend='gsplat' needs Gaussians on a CUDA device")
    uv, z, conic, radius, opac, colors = _prepare(gaussians, camera, near)
    H, W = camera.height, camera.width
    dt = uv.dtype
    ids, offs, counts, tx, ty = _bin(uv, radius, z, W, H, tile)
    C = torch.zeros(H, W, 3, dtype=dt)
    D = torch.zeros(H, W, dtype=dt)
    T = torch.ones(H, W, dtype=dt)
    Cs, Ds, Ts, slots = [], [], [], []
    for t in torch.nonzero(counts).reshape(-1).tolist():
        ty0, tx0 = (t // tx) * tile, (t % tx) * tile
        ty1, tx1 = min(ty0 + tile, H), min(tx0 + tile, W)
        pix = _pixels(tx0, tx1, ty0, ty1, dt)
        g_all = ids[offs[t]:offs[t] + counts[t]]
        Ct = torch.zeros(len(pix), 3, dtype=dt)
        Dt = torch.zeros(len(pix), dtype=dt)
        Tt = torch.ones(len(pix), dtype=dt)
        for s in range(0, len(g_all), chunk):
            g = g_all[s:s + chunk]
            a = _alpha(pix, uv[g], conic[g], opac[g], radius[g])
            c, d, Tt = _composite(a, Tt, colors[g], z[g])
            Ct, Dt = Ct + c, Dt + d
            if bool((Tt < T_MIN).all()) if Tt.numel() else True:
                break
        Cs.append(Ct); Ds.append(Dt); Ts.append(Tt); slots.append((ty0, ty1, tx0, tx1))
    if slots:  # scatter tile results into the image without in-place ops on graph tensors
        idx = torch.cat([(torch.arange(a, b)[:, None] * W + torch.arange(c, d)[None]).reshape(-1)
                         for a, b, c, d in slots])
        C = C.reshape(-1, 3).index_put((idx,), torch.cat(Cs))
        D = D.reshape(-1).index_put((idx,), torch.cat(Ds))
        T = T.reshape(-1).index_put((idx,), torch.cat(Ts))
    return _finish(C.reshape(-1, 3), D.reshape(-1), T.reshape(-1), background, H, W)
