"""Differentiable Gaussian rasterizer on CPU (vectorised torch), with a slow reference.

Pipeline (3DGS, Kerbl et al. 2023):
  1. world → camera; cull Gaussians with z <= near.
  2. EWA: Σ2d = J W Σ Wᵀ Jᵀ + 0.3·I (the 0.3-pixel² low-pass), J the projection Jacobian.
  3. radius r = ceil(3·sqrt(λmax(Σ2d))); a Gaussian touches the pixels of its square
     [u−r, u+r]×[v−r, v+r] only (in both the tiled path and the reference, so they agree).
  4. tile binning: (tile, Gaussian) pairs built with repeat_interleave, sorted by
     (tile, depth) with one argsort.
  5. front-to-back compositing, all tiles at once: tiles ordered by load and taken in groups
     (tiles × pixels × chunk ≤ BATCH_ELEMS_*), each round evaluating the next ``chunk``
     depth-sorted Gaussians of every active tile ([tiles, pixels, chunk]; short lists padded
     with a transparent slot), α = min(0.99, o·exp(−½ dᵀ Σ2d⁻¹ d)), α < 1/255 skipped, a
     Gaussian used only while T·(1−α) ≥ 1e-4 (early termination), T carried across rounds,
     a tile dropped once exhausted or saturated; C = Σ T_i α_i c_i + T_final · background.
     The round has a hand-written backward (:class:`_CompositeRound`) that keeps only α.
Complexity: O(P + Σ_tiles n_tile · tile²) work; memory O(BATCH_ELEMS) per round plus one α per
(tile pixel, Gaussian) kept for the backward. The Python loop runs over tile groups and rounds,
never over tiles, pixels or Gaussians.
Outputs: rgb [H, W, 3], alpha [H, W] = 1 − T_final, depth [H, W] = Σ T_i α_i z_i / alpha
(0 where alpha = 0).
"""
from __future__ import annotations

import math

import torch

from geoface.camera import Camera
from geoface.splat.errors import SplatError

LOWPASS = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
BATCH_ELEMS_CPU = 1 << 22  # tiles × pixels × chunk per compositing step (CPU)
BATCH_ELEMS_GPU = 1 << 25


def project_gaussians(means, covs, camera: Camera, near=0.01):
    """EWA projection. means [N,3], covs [N,3,3] → uv [N,2], depth [N], conic [N,2,2],
    radius [N] (int, 0 = culled)."""
    W = torch.as_tensor(camera.R, dtype=means.dtype, device=means.device)
    Xc = camera.world_to_camera(means)  # [N, 3]
    x, y, z = Xc.unbind(-1)
    valid = z > near
    zs = torch.where(valid, z, torch.ones_like(z))
    fx, fy = camera.fx, camera.fy
    uv = torch.stack([fx * x / zs + camera.cx, fy * y / zs + camera.cy], -1)
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * x / zs**2, zero, fy / zs, -fy * y / zs**2], -1).reshape(-1, 2, 3)
    M = J @ W  # [N, 2, 3]
    cov2 = M @ covs @ M.transpose(-1, -2) + LOWPASS * torch.eye(2, dtype=means.dtype, device=means.device)
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
    """pix [...,P,2], per-Gaussian uv [...,G,2], conic [...,G,2,2], opac [...,G], radius [...,G]
    → α [...,P,G] (leading dims: none for one tile, [tiles] for the batched path)."""
    d = pix[..., :, None, :] - uv[..., None, :, :]  # [..., P, G, 2]
    dx, dy = d[..., 0], d[..., 1]
    power = -0.5 * (conic[..., None, :, 0, 0] * dx ** 2 + conic[..., None, :, 1, 1] * dy ** 2
                    + 2 * conic[..., None, :, 0, 1] * dx * dy)
    alpha = torch.clamp_max(opac[..., None, :] * torch.exp(power), ALPHA_MAX)
    with torch.no_grad():
        r = radius.to(pix.dtype)[..., None, :]
        keep = (dx.abs() <= r) & (dy.abs() <= r) & (alpha >= ALPHA_MIN) & (power <= 0)
    return torch.where(keep, alpha, torch.zeros_like(alpha))


def _pixels(x0, x1, y0, y1, dtype, device=None):
    ys, xs = torch.meshgrid(torch.arange(y0, y1, dtype=dtype, device=device),
                            torch.arange(x0, x1, dtype=dtype, device=device), indexing="ij")
    return torch.stack([xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5], -1)


def _prepare(gaussians, camera, near):
    if not isinstance(camera, Camera):
        raise SplatError(f"camera must be a geoface.camera.Camera; got {type(camera).__name__}")
    uv, z, conic, radius = project_gaussians(gaussians.means, gaussians.covariances(), camera, near)
    colors = gaussians.rgb(camera.center)
    return uv, z, conic, radius, gaussians.opacities(), colors


def _finish(C, D, T, background, H, W):
    alpha = 1 - T
    rgb = C
    if background is not None:
        bg = torch.as_tensor(background, dtype=C.dtype, device=C.device)
        rgb = C + T[:, None] * bg
    depth = torch.where(alpha > 0, D / torch.where(alpha > 0, alpha, torch.ones_like(alpha)),
                        torch.zeros_like(D))
    return rgb.reshape(H, W, 3), alpha.reshape(H, W), depth.reshape(H, W)


def _composite(alpha, T0, colors, z):
    """alpha [...,P,G] (depth order), T0 [...,P], colors [...,G,3], z [...,G]
    → (C [...,P,3], D [...,P], T [...,P]) with early termination."""
    with torch.no_grad():  # T after each Gaussian decides which ones are used
        used = T0[..., None] * torch.cumprod(1 - alpha, -1) >= T_MIN
    a = torch.where(used, alpha, torch.zeros_like(alpha))
    one = torch.ones_like(a[..., :1])
    Tin = T0[..., None] * torch.cumprod(torch.cat([one, 1 - a[..., :-1]], -1), -1)  # T before each
    w = Tin * a
    return w @ colors, (w @ z[..., None])[..., 0], Tin[..., -1] * (1 - a[..., -1])


def _info(uv, radius, W, H):
    """The 4th return value of ``return_info=True``: 2D means (in the graph, pixels) and radii
    (0 for Gaussians culled or whose 3σ box misses the image)."""
    with torch.no_grad():
        u, v, r = uv[:, 0], uv[:, 1], radius.to(uv.dtype)
        on = (u + r >= 0) & (u - r <= W) & (v + r >= 0) & (v - r <= H)
        radii = torch.where(on, radius, torch.zeros_like(radius))
    return {"means2d": uv, "radii": radii, "width": W, "height": H}


def rasterize_reference(gaussians, camera: Camera, background=None, near=0.01,
                        return_info: bool = False):
    """Slow, obvious rasterizer: all Gaussians × all pixels, one global depth sort."""
    uv, z, conic, radius, opac, colors = _prepare(gaussians, camera, near)
    H, W = camera.height, camera.width
    dt, dev = uv.dtype, uv.device
    live = torch.nonzero(radius > 0).reshape(-1)
    live = live[torch.argsort(z[live].detach(), stable=True)]
    pix = _pixels(0, W, 0, H, dt, dev)
    if len(live) == 0:
        T = torch.ones(H * W, dtype=dt, device=dev)
        out = _finish(torch.zeros(H * W, 3, dtype=dt, device=dev), torch.zeros(H * W, dtype=dt, device=dev),
                      T, background, H, W)
    else:
        alpha = _alpha(pix, uv[live], conic[live], opac[live], radius[live])
        C, D, T = _composite(alpha, torch.ones(H * W, dtype=dt, device=dev), colors[live], z[live])
        out = _finish(C, D, T, background, H, W)
    return (*out, _info(uv, radius, W, H)) if return_info else out


def _bin(uv, radius, z, W, H, tile):
    """(tile id, Gaussian id) pairs sorted by tile then depth; returns ids, tile offsets, counts."""
    dev = uv.device
    tx, ty = math.ceil(W / tile), math.ceil(H / tile)
    u, v = uv.detach()[:, 0], uv.detach()[:, 1]
    r = radius.to(u.dtype)
    x0 = torch.clamp(torch.floor((u - r) / tile), 0, tx).to(torch.int64)
    x1 = torch.clamp(torch.floor((u + r) / tile), -1, tx - 1).to(torch.int64)
    y0 = torch.clamp(torch.floor((v - r) / tile), 0, ty).to(torch.int64)
    y1 = torch.clamp(torch.floor((v + r) / tile), -1, ty - 1).to(torch.int64)
    nx, ny = torch.clamp_min(x1 - x0 + 1, 0), torch.clamp_min(y1 - y0 + 1, 0)
    cnt = torch.where(radius > 0, nx * ny, torch.zeros_like(nx))
    gid = torch.repeat_interleave(torch.arange(len(uv), device=dev), cnt)
    start = torch.cumsum(cnt, 0) - cnt
    k = torch.arange(len(gid), device=dev) - start[gid]
    tid = (y0[gid] + k // nx[gid]) * tx + x0[gid] + k % nx[gid]
    order_z = torch.argsort(z.detach(), stable=True)
    rank_all = torch.empty(len(uv), dtype=torch.int64, device=dev)
    rank_all[order_z] = torch.arange(len(uv), device=dev)
    order = torch.argsort(tid * len(uv) + rank_all[gid])
    counts = torch.bincount(tid, minlength=tx * ty)
    return gid[order], torch.cumsum(counts, 0) - counts, counts, tx, ty


def _batch_elems(device) -> int:
    """Bound on tiles × pixels × chunk evaluated at once (each [..] float tensor of the step)."""
    return BATCH_ELEMS_CPU if device.type == "cpu" else BATCH_ELEMS_GPU


# per-Gaussian feature columns gathered once per round: u v | conic a b c | opacity | radius | z rgb
_U, _V, _CA, _CB, _CC, _O, _R, _Z = 0, 1, 2, 3, 4, 5, 6, 7


def _round_alpha(lc, org, feat):
    """Batched :func:`_alpha` over A tiles of t×t pixels: lc [t] pixel-centre offsets from the tile
    centre, org [A,2] tile centres, feat [A,L,F] → α [A,t·t,L]. Separable: dx depends on the
    column only and dy on the row only, so most terms are [A,1,t,L] or [A,t,1,L]."""
    A, L = feat.shape[:2]
    t = len(lc)
    du = org[:, None, :] - feat[..., _U:_V + 1]  # [A, L, 2]
    dx = lc[None, None, :, None] + du[:, None, None, :, 0]  # [A, 1, t, L]
    dy = lc[None, :, None, None] + du[:, None, None, :, 1]  # [A, t, 1, L]
    a, b, c, o, r = (feat[:, None, None, :, k] for k in (_CA, _CB, _CC, _O, _R))
    power = (-0.5 * a * dx * dx + -0.5 * c * dy * dy) - (b * dx) * dy  # [A, t, t, L]
    raw = o * torch.exp(power)
    keep = ((dx.abs() <= r) & (dy.abs() <= r)) & (raw >= ALPHA_MIN) & (power <= 0)
    alpha = torch.where(keep, torch.clamp_max(raw, ALPHA_MAX), torch.zeros_like(raw))
    return alpha.reshape(A, t * t, L)


class _CompositeRound(torch.autograd.Function):
    """One compositing round for A tiles × L Gaussians (same maths as :func:`_alpha` +
    :func:`_composite`, which the reference path runs through autograd; the tests compare the
    two, gradcheck included) with an analytic backward — the 3DGS backward, vectorised:

        w_i = T0·Trel_i·α_i,  Trel_i = Π_{j<i}(1 − α_j),  k_i = c_i·∂L/∂C + z_i·∂L/∂D
        ∂L/∂α_i = T0·(Trel_i·k_i − (Σ_{j>i} Trel_j α_j k_j + Tout·∂L/∂T) / (1 − α_i))
        ∂L/∂power = α·∂L/∂α (where α is not clamped);  ∂L/∂o = Σ_p ∂L/∂power / o

    and the sums over pixels of ∂L/∂power · {1, dx, dy, dx², dy², dx·dy} come from six pixel
    moments (one matmul), since dx = lx_p + (ox − u) splits into a pixel and a Gaussian part.
    Only the used α [A, P, L] is kept for the backward. ``done`` [A, P] marks pixels whose
    compositing already stopped (3DGS: the first Gaussian that would bring T below T_MIN ends
    the pixel, later ones are not used even if T would stay above T_MIN); it is returned
    updated, so rounds chain exactly like one pass over the whole list.
    """

    @staticmethod
    def forward(ctx, lc, org, feat, T0, done):  # [t], [A,2], [A,L,F], [A,P], [A,P] bool
        alpha = _round_alpha(lc, org, feat)
        incl = torch.cumprod(1 - alpha, -1)  # T/T0 after each Gaussian
        used = ~done[..., None] & (T0[..., None] * incl >= T_MIN)  # a prefix along L
        a = torch.where(used, alpha, torch.zeros_like(alpha))
        Trel = torch.cat([torch.ones_like(incl[..., :1]), incl[..., :-1]], -1)  # = masked one where used
        zc = (Trel * a) @ feat[..., _Z:]  # [A, P, 4]: depth, rgb
        Tout = torch.where(used, incl, torch.ones_like(incl)).amin(-1)
        ctx.save_for_backward(lc, org, feat, T0, a)
        done = done | ~used[..., -1]
        ctx.mark_non_differentiable(done)
        return T0[..., None] * zc[..., 1:], T0 * zc[..., 0], T0 * Tout, done

    @staticmethod
    def backward(ctx, gC, gD, gT, _gdone):
        lc, org, feat, T0, a = ctx.saved_tensors
        one_m = 1 - a
        incl = torch.cumprod(one_m, -1)
        Trel = torch.cat([torch.ones_like(incl[..., :1]), incl[..., :-1]], -1)
        Tout = incl[..., -1]
        wrel = Trel * a
        gzc = torch.cat([gD[..., None], gC], -1)  # [A, P, 4]
        k = gzc @ feat[..., _Z:].transpose(-1, -2)  # [A, P, L]
        g_zc = wrel.transpose(-1, -2) @ (T0[..., None] * gzc)  # [A, L, 4]
        wk = wrel * k
        tot = wk.sum(-1, keepdim=True)
        after = tot - torch.cumsum(wk, -1) + (Tout * gT)[..., None]
        g_a = T0[..., None] * (Trel * k - after / one_m)
        live = (a > 0) & (a < ALPHA_MAX)
        g_p = torch.where(live, g_a * a, torch.zeros_like(a))  # ∂L/∂power
        g_T0 = tot[..., 0] + Tout * gT
        t = len(lc)
        lx, ly = lc.repeat(t), lc.repeat_interleave(t)  # pixel p = row·t + column
        M = torch.stack([torch.ones_like(lx), lx, ly, lx * lx, ly * ly, lx * ly])  # [6, P]
        m0, mx, my, mxx, myy, mxy = (M @ g_p).unbind(1)  # [A, L] each
        du = org[:, None, :] - feat[..., _U:_V + 1]
        ux, uy = du[..., 0], du[..., 1]
        sx, sy = mx + ux * m0, my + uy * m0  # Σ_p g·dx, Σ_p g·dy
        sxx = mxx + 2 * ux * mx + ux * ux * m0
        syy = myy + 2 * uy * my + uy * uy * m0
        sxy = mxy + ux * my + uy * mx + ux * uy * m0
        ca, cb, cc, o = feat[..., _CA], feat[..., _CB], feat[..., _CC], feat[..., _O]
        g_o = torch.where(o > 0, m0 / torch.where(o > 0, o, torch.ones_like(o)), torch.zeros_like(o))
        g_feat = torch.stack([ca * sx + cb * sy, cc * sy + cb * sx,  # ∂power/∂u = a dx + b dy
                              -0.5 * sxx, -sxy, -0.5 * syy, g_o, torch.zeros_like(g_o)], -1)
        return None, None, torch.cat([g_feat, g_zc], -1), g_T0, None


def _composite_tiles(uv, z, conic, opac, colors, radius, ids, offs, counts, tx, ty, tile, chunk,
                     W, H):
    """Batched tile compositing → per-tile (C [nt,P,3], D [nt,P], T [nt,P]), P = tile².

    Tiles are ordered by load and processed in groups; each round evaluates the next ``L``
    depth-sorted Gaussians of every still-active tile at once ([tiles, P, L]), padding short
    lists with a transparent slot (α = 0 exactly, so padding changes nothing). T and the
    per-pixel "done" flag are carried across rounds; a tile leaves the group when its list is
    exhausted or all its pixels are done — further rounds could only add zero weights, so the
    result equals one pass over each tile's whole list, i.e. the reference.
    """
    dt, dev = uv.dtype, uv.device
    nt, P = tx * ty, tile * tile
    C = torch.zeros(nt, P, 3, dtype=dt, device=dev)
    D = torch.zeros(nt, P, dtype=dt, device=dev)
    T = torch.ones(nt, P, dtype=dt, device=dev)
    if len(ids) == 0:
        return C, D, T
    n = len(uv)
    feat = torch.cat([uv, conic[:, 0, 0, None], conic[:, 0, 1, None], conic[:, 1, 1, None], opac[:, None],
                      radius.to(dt)[:, None], z[:, None], colors], 1)
    feat = torch.cat([feat, torch.zeros_like(feat[:1])])  # row n: the transparent padding slot
    loc = _pixels(0, tile, 0, tile, dt, dev)  # [P, 2] local pixel centres
    lc = torch.arange(tile, dtype=dt, device=dev) + 0.5 - 0.5 * tile  # centre offsets
    counts_h = counts.cpu()
    busy = torch.nonzero(counts_h).reshape(-1)
    busy = busy[torch.argsort(counts_h[busy], descending=True, stable=True)].tolist()
    budget = _batch_elems(dev)
    out_t, out_C, out_D, out_T = [], [], [], []
    i = 0
    while i < len(busy):
        L = min(chunk, int(counts_h[busy[i]]))  # the group's longest list comes first
        n_grp = max(1, budget // (P * L))
        grp_h = busy[i:i + n_grp]
        i += n_grp
        grp = torch.tensor(grp_h, device=dev)
        n_g, o_g = counts[grp], offs[grp]
        org = torch.stack([(grp % tx) * tile, (grp // tx) * tile], -1).to(dt)  # [G, 2]
        inside = ((loc[None, :, 0] + org[:, None, 0] < W) & (loc[None, :, 1] + org[:, None, 1] < H))
        Cg = torch.zeros(len(grp_h), P, 3, dtype=dt, device=dev)
        Dg = torch.zeros(len(grp_h), P, dtype=dt, device=dev)
        Tg = inside.to(dt)
        done = ~inside  # pixels of edge tiles beyond the image take no part
        act = torch.arange(len(grp_h), device=dev)
        full = True  # act is every tile of the group
        pos0 = torch.arange(L, device=dev)
        for r in range(-(-int(counts_h[grp_h].max()) // L)):
            pos = r * L + pos0
            na = n_g[act][:, None]
            g = torch.where(pos[None] < na, ids[torch.clamp_max(o_g[act][:, None] + pos, len(ids) - 1)], n)
            c, d, Tn, dn = _CompositeRound.apply(lc, org[act] + 0.5 * tile, feat[g], Tg if full else Tg[act],
                                                 done if full else done[act])
            if full:
                Cg, Dg, Tg, done = Cg + c, Dg + d, Tn, dn
            else:
                Cg, Dg, Tg = Cg.index_add(0, act, c), Dg.index_add(0, act, d), Tg.index_copy(0, act, Tn)
                done = done.index_copy(0, act, dn)
            more = torch.nonzero(((r + 1) * L < na[:, 0]) & ~dn.all(-1)).reshape(-1)
            if len(more) == 0:
                break
            if len(more) < len(act):
                act, full = act[more], False
        out_t.append(grp); out_C.append(Cg); out_D.append(Dg); out_T.append(Tg)
    t = torch.cat(out_t)
    return (C.index_put((t,), torch.cat(out_C)), D.index_put((t,), torch.cat(out_D)),
            T.index_put((t,), torch.cat(out_T)))


def auto_tile(radius) -> int:
    """Tile size for the batched path from the median screen radius (pixels) of the visible
    Gaussians: 4 up to r = 8, 8 up to r = 48, else 16. Work per (tile, Gaussian) pair is
    tile² while the number of pairs grows as (2r/tile + 1)²; the thresholds come from timing
    forward + backward on head-like scenes (bench/bench_splat.py, r ≈ 3–10) and on scenes of
    larger overlapping splats (r ≈ 14 and 60) on CPU."""
    r = radius[radius > 0]
    if len(r) == 0:
        return 16
    med = float(r.median())
    return 4 if med <= 8 else 8 if med <= 48 else 16


def rasterize(gaussians, camera: Camera, background=None, tile: int | None = None, chunk: int | None = None,
              near: float = 0.01, backend: str = "auto", return_info: bool = False):
    """Render ``gaussians`` seen by ``camera`` → (rgb [H,W,3], alpha [H,W], depth [H,W]).

    ``backend``: "torch" (this vectorised path, any device), "gsplat" (CUDA; needs gsplat), or
    "auto" (gsplat when importable and the tensors live on CUDA, else torch). Differentiable
    with respect to every Gaussian parameter (autograd around a hand-written backward of the
    compositing rounds). ``tile``: tile size in pixels (None: :func:`auto_tile` on CPU, 16 on a
    GPU); ``chunk``: Gaussians per tile evaluated per compositing round (None: 16 on CPU, 256
    on a GPU, where fewer, larger rounds pay less launch overhead). Neither changes the result.

    ``return_info=True`` adds a 4th value, a dict: ``"means2d"`` [N, 2] the projected means in
    pixels, a tensor in the graph (call ``retain_grad()`` on it before ``backward`` to read the
    screen-space gradient, as density control does), ``"radii"`` [N] int (0 = not visible),
    ``"width"``, ``"height"``.
    """
    if backend not in ("auto", "torch", "gsplat"):
        raise SplatError(f"backend must be 'auto', 'torch' or 'gsplat'; got {backend!r}")
    if (tile is not None and tile < 1) or (chunk is not None and chunk < 1):
        raise SplatError(f"tile and chunk must be >= 1; got tile={tile}, chunk={chunk}")
    if backend != "torch" and gaussians.means.is_cuda:
        from geoface.splat._gsplat import rasterize_gsplat, gsplat_available
        if backend == "gsplat" or gsplat_available():
            return rasterize_gsplat(gaussians, camera, background, near, return_info=return_info)
    elif backend == "gsplat":
        raise SplatError("backend='gsplat' needs Gaussians on a CUDA device")
    uv, z, conic, radius, opac, colors = _prepare(gaussians, camera, near)
    H, W = camera.height, camera.width
    cpu = uv.device.type == "cpu"
    if tile is None:
        tile = auto_tile(radius) if cpu else 16
    if chunk is None:
        chunk = 16 if cpu else 256
    ids, offs, counts, tx, ty = _bin(uv, radius, z, W, H, tile)
    C, D, T = _composite_tiles(uv, z, conic, opac, colors, radius, ids, offs, counts, tx, ty,
                               tile, chunk, W, H)
    # image pixel (y, x) ← tile (y // tile, x // tile), local pixel (y % tile, x % tile)
    ys = torch.arange(H, device=uv.device)[:, None]
    xs = torch.arange(W, device=uv.device)[None]
    pmap = (((ys // tile) * tx + xs // tile) * (tile * tile) + (ys % tile) * tile + xs % tile).reshape(-1)
    out = _finish(C.reshape(-1, 3)[pmap], D.reshape(-1)[pmap], T.reshape(-1)[pmap], background, H, W)
    return (*out, _info(uv, radius, W, H)) if return_info else out
