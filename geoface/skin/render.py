"""Procedural skin PBR maps and their shading (synthetic data for the 4K-texture model).

:func:`skin_maps` draws UV-space maps at any resolution from a seed — the same seed gives the
same skin at every resolution (features are placed in UV units and noise is drawn on grids
that do not depend on the resolution; a lower resolution sees fine features averaged):

* albedo [R, R, 3] in [0, 1] — a skin tone, low-frequency redness patches, freckles (sparse
  brown spots in a few regions), pores (dense small dark dots) and fine mottling;
* height [R, R] — pore pits and fine wrinkles; **micronormal** [R, R, 3] = tangent-space
  normal of the height field, encoded n/2 + ½ (so flat skin is (0.5, 0.5, 1));
* specular [R, R, 1] in [0, 1] — an oily T-zone-like low-frequency field, less in pores.

:func:`shade` renders per-pixel maps under a few directional lights (an environment
approximation) with Lambert diffuse plus a GGX microfacet specular lobe, using the
micronormal through a per-pixel tangent frame; output is display-referred RGB in [0, 1]
(gamma 2.2).  All numpy, vectorised.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from . import SkinError

#: skin tones (linear-ish sRGB albedo), light to dark
TONES = np.array([[0.85, 0.66, 0.55], [0.78, 0.57, 0.45], [0.68, 0.47, 0.36],
                  [0.55, 0.37, 0.27], [0.40, 0.26, 0.19], [0.28, 0.18, 0.13]])


def periodic_noise(rng, R: int, scale_uv: float) -> np.ndarray:
    """Smooth periodic noise with features of about ``scale_uv`` (UV units), zero mean, unit std.

    Drawn on a grid of fixed size (4 cells per feature, whatever ``R``) and resampled, so the
    same generator state gives the same field at every resolution."""
    return _aniso_noise(rng, R, scale_uv, scale_uv)


def _spots(rng, R: int, count: int, sigma_uv: float, amp: tuple[float, float]) -> np.ndarray:
    """Sum of ``count`` Gaussian spots of width ``sigma_uv`` at random UV positions.

    Positions are drawn in UV units and the image integral is kept (each spot adds
    amplitude·2πσ² in UV area), so lower resolutions see the same spots, averaged."""
    img = np.zeros((R, R))
    if count:
        uv = rng.random((count, 2))
        a = rng.uniform(*amp, count)
        ij = np.minimum((uv * R).astype(np.int64), R - 1)
        np.add.at(img, (ij[:, 0], ij[:, 1]), a)
        s = sigma_uv * R
        img = ndimage.gaussian_filter(img, s, mode="wrap") * (2 * np.pi * s * s) if s >= 0.5 \
            else img * (2 * np.pi * s * s)  # sub-pixel spots: area-weighted impulses
    return img


@dataclass
class SkinMaps:
    albedo: np.ndarray  # [R, R, 3]
    height: np.ndarray  # [R, R]
    micronormal: np.ndarray  # [R, R, 3] encoded n/2 + 1/2
    specular: np.ndarray  # [R, R, 1]

    def stack(self) -> np.ndarray:  # [R, R, 7] in the model's map order
        return np.concatenate([self.albedo, self.micronormal, self.specular], -1).astype(np.float32)


def height_to_normal(height: np.ndarray, strength: float) -> np.ndarray:
    """Tangent-space normal of a height field given in UV units (h per unit UV), encoded to [0, 1]."""
    R = height.shape[0]
    hu = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) * (R / 2)  # ∂h/∂u
    hv = (np.roll(height, -1, 0) - np.roll(height, 1, 0)) * (R / 2)  # ∂h/∂v
    n = np.stack([-strength * hu, -strength * hv, np.ones_like(height)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n * 0.5 + 0.5


#: the noise grids' blur (cells): a feature is about four cells
NOISE_BLUR = 4.0


def _blurred_where_read(noise, R: int) -> np.ndarray:
    """``ndimage.gaussian_filter(noise, NOISE_BLUR, mode="wrap")`` where a linear resampling of the
    grid to ``R``² reads it (the cells either side of each sample, and one more), zeros elsewhere:
    the same numbers, to the last bit, as the whole filter gives there (SciPy's symmetric
    correlation, rows then columns: the centre tap, then the taps' pairs from the outermost in),
    at a fraction of its cost when ``R`` is far below the grid's size."""
    r = int(4.0 * NOISE_BLUR + 0.5)  # gaussian_filter's radius (truncate = 4)
    impulse = np.zeros(2 * r + 1)
    impulse[r] = 1.0
    w = ndimage.gaussian_filter1d(impulse, NOISE_BLUR, mode="constant")  # its weights, exactly (symmetric)

    def read(G):  # the cells the resampling reads: floor(c) and floor(c) + 1, with a cell's margin
        c = (np.arange(R) + 0.5) * G / R - 0.5
        return np.unique(((np.floor(c).astype(np.int64)[:, None] + np.arange(-1, 3)) % G).ravel())

    def correlate(z, idx, axis):
        n = z.shape[axis]
        acc = np.take(z, idx, axis=axis) * w[r]
        for j in range(-r, 0):
            acc += (np.take(z, (idx + j) % n, axis=axis) + np.take(z, (idx - j) % n, axis=axis)) * w[r + j]
        return acc

    rows, cols = read(noise.shape[0]), read(noise.shape[1])
    out = np.zeros_like(noise)
    out[np.ix_(rows, cols)] = correlate(correlate(noise, rows, 0), cols, 1)
    return out


def _aniso_noise(rng, R: int, scale_u: float, scale_v: float) -> np.ndarray:
    """Smooth noise with features of ``scale_u`` across and ``scale_v`` up the UV square (lines
    along the longer one); zero mean, unit std, the same field at every resolution."""
    Gu, Gv = (max(int(np.ceil(4.0 / s)), 4) for s in (scale_u, scale_v))
    noise = rng.standard_normal((Gv, Gu))
    if 16 * R <= min(Gu, Gv):  # a small map of a fine grid: the filter only where the resampling reads
        z = _blurred_where_read(noise, R)
    else:
        z = ndimage.gaussian_filter(noise, NOISE_BLUR, mode="wrap")
    z = ndimage.zoom(z, (R / Gv, R / Gu), order=1, mode="grid-wrap", grid_mode=True)
    z = np.pad(z, ((0, max(R - z.shape[0], 0)), (0, max(R - z.shape[1], 0))), mode="wrap")[:R, :R]
    z = z - z.mean()
    return z / (z.std() + 1e-12)


def _regional(p: dict, rng_for, res: int, regions: dict, albedo, height, spec, hair: np.ndarray) -> None:
    """Region-dependent skin, in place (see :func:`skin_maps`)."""
    g = {k: np.asarray(regions.get(k, 0.0), np.float64) for k in ("lips", "brows", "eyelids", "nose", "cheeks",
                                                                     "forehead", "beard")}
    # lips: redder and darker, no pores, fine vertical lines, shinier
    lip = albedo * np.array([0.95, 0.62, 0.66])
    albedo += g["lips"][..., None] * (lip - albedo)
    height += g["lips"] * _aniso_noise(rng_for(10), res, 0.0015, 0.02) * 1.2e-4
    spec += 0.15 * g["lips"]
    # brows: short hair strokes along the brow, dark (the person's hair colour)
    strokes = _spots(rng_for(11), res, 200_000, 3e-4, (0.5, 1.0))  # hair roots (per unit UV area)
    strokes = ndimage.gaussian_filter1d(strokes, 2.5e-3 * res, axis=1) * (2.5e-3 * res * np.sqrt(2 * np.pi))
    strokes = np.clip(strokes / (2 * np.pi * (3e-4 * res) ** 2 + 1e-12) * 0.5, 0, 1) * g["brows"]
    albedo += strokes[..., None] * 0.85 * (hair - albedo)
    height += strokes * 1e-4
    # eyelids: fine horizontal folds, slightly darker and pinker
    height += g["eyelids"] * _aniso_noise(rng_for(12), res, 0.03, 0.0015) * 1.5e-4
    albedo *= (1 - g["eyelids"][..., None] * np.array([0.04, 0.10, 0.08]))
    # forehead: horizontal lines, their depth the person's
    lines = np.sin(2 * np.pi * (uv_grid_v(res) / 0.011 + 0.8 * periodic_noise(rng_for(13), res, 0.05)))
    height += g["forehead"] * p["lines"] * np.clip(lines, -1, 1) * 1.2e-4
    # T-zone shine; redness on cheeks and nose
    spec += 0.18 * g["nose"] + 0.08 * g["forehead"] - 0.05 * g["cheeks"]
    albedo += (0.6 * g["cheeks"] + 0.3 * g["nose"])[..., None] * p["redness"] * np.array([0.10, -0.05, -0.04])
    # stubble: dense short dark hairs in the beard area
    if p["stubble"] > 0:
        st = np.clip(_spots(rng_for(14), res, int(4e5 * p["stubble"]), 2e-4, (0.6, 1.0)), 0, 1.5) * g["beard"]
        albedo += np.clip(st, 0, 1)[..., None] * 0.7 * (hair - albedo)
        height += st * 5e-5


def uv_grid_v(res: int) -> np.ndarray:
    return np.broadcast_to((1.0 - (np.arange(res) + 0.5) / res)[:, None], (res, res))


def skin_maps(res: int = 1024, seed: int = 0, *, pore_density: float = 3e5, freckles: float | None = None,
              redness: float | None = None, tone: int | None = None, regions: dict | None = None) -> SkinMaps:
    """Random skin at ``res``² (see the module docstring).  ``pore_density`` = pores per unit UV area.

    ``regions``: soft masks ``{name: [res, res]}`` of a face layout
    (:func:`geoface.skin.regions.ict_uv_regions`).  With them the skin varies by region:
    pores large and dense on the nose, fewer on the forehead, none on lips and eyelids; lips
    red, lined and shiny; brows of hair strokes in the person's hair colour; fine folds on the
    eyelids; horizontal forehead lines; a shiny T-zone; redness and freckles on cheeks and nose;
    stubble in the beard area for some people.  Without them the skin is the same everywhere."""
    if not 16 <= res <= 8192:
        raise SkinError(f"res must be in 16..8192; got {res}")
    for k, m in (regions or {}).items():
        if np.ndim(m) and np.shape(m) != (res, res):
            raise SkinError(f"region {k!r} is {np.shape(m)}; the maps are {res}x{res}")
    rng = np.random.default_rng(seed)
    p = {"tone": int(rng.integers(len(TONES))) if tone is None else int(tone),
         "freckles": float(rng.uniform(0, 1)) if freckles is None else float(freckles),
         "redness": float(rng.uniform(0.1, 0.6)) if redness is None else float(redness)}
    # person traits of the regional skin, from their own stream (the draws above stay as they were)
    traits = np.random.default_rng([seed, 99])
    p.update(lines=float(traits.uniform(0.1, 1.0)), stubble=float(traits.uniform(0.2, 1.0) if traits.random() < 0.4 else 0.0))
    hair = np.array([[0.06, 0.04, 0.03], [0.16, 0.10, 0.06], [0.35, 0.24, 0.14], [0.55, 0.42, 0.25]])[traits.integers(4)]
    # every feature draws from its own stream, so counts do not shift the others
    sub = [np.random.default_rng([seed, k]) for k in range(8)]
    base = TONES[p["tone"]] * (1 + 0.04 * rng.standard_normal(3))
    albedo = np.broadcast_to(base, (res, res, 3)).copy()
    mott = periodic_noise(sub[0], res, 0.01)
    fine = periodic_noise(sub[7], res, 0.0012)  # fine skin texture, about a pixel at 1K: what HFDR must restore
    albedo *= (1 + 0.025 * mott + 0.06 * fine)[..., None]
    red = np.clip(periodic_noise(sub[1], res, 0.08), 0, None) * p["redness"]
    albedo += red[..., None] * np.array([0.10, -0.05, -0.04])
    region = np.clip(periodic_noise(sub[2], res, 0.15) - 0.3, 0, None)  # where freckles gather
    if regions is not None:  # on the cheeks and the nose
        region = 1.5 * (np.asarray(regions.get("cheeks", 0.0)) + np.asarray(regions.get("nose", 0.0)))
    n_freck = int(2000 * p["freckles"])
    freck = _spots(sub[3], res, n_freck, 1.5e-3, (0.4, 1.0)) * np.minimum(region, 1.0)
    albedo *= 1 - 0.45 * np.clip(freck, 0, 1)[..., None] * np.array([0.6, 0.8, 1.0])
    pores = _spots(sub[4], res, int(pore_density), 2.5e-4, (0.5, 1.0))
    if regions is not None:  # density by region; large pores on the nose
        g = {k: np.asarray(regions.get(k, 0.0)) for k in ("lips", "eyelids", "nose", "forehead", "cheeks")}
        pores = pores * np.clip(1 - g["lips"] - 0.9 * g["eyelids"] - 0.4 * g["forehead"] + 0.3 * g["cheeks"], 0, None)
        pores += _spots(sub[4], res, int(pore_density / 3), 4.5e-4, (0.6, 1.0)) * 1.6 * g["nose"]
    pores = np.clip(pores, 0, 1.5)
    albedo *= 1 - 0.12 * pores[..., None]
    wrinkles = periodic_noise(sub[5], res, 0.002) * 0.3
    height = (-pores + wrinkles) * 2e-4  # UV units (1 = the UV square's side)
    micronormal = height_to_normal(height, strength=1.0)
    spec = 0.35 + 0.15 * periodic_noise(sub[6], res, 0.1) - 0.15 * pores + 0.06 * fine
    if regions is not None:
        _regional(p, lambda k: np.random.default_rng([seed, k]), res, regions, albedo, height, spec, hair)
        micronormal = height_to_normal(height, strength=1.0)
    return SkinMaps(np.clip(albedo, 0, 1), height, micronormal, np.clip(spec, 0, 1)[..., None])


def random_lights(rng, n: int = 3, *, power: tuple[float, float] = (0.9, 1.2)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(directions [n, 3] towards the lights, colours [n, 3], ambient [3]) around a frontal hemisphere.

    The lights share a total power drawn from ``power`` (a photo's exposure: a face facing a
    light of power 1 is as bright as its albedo), split unevenly between them, with a warm/cool
    tint of ±15 % per channel; so the photo's brightness says something about the skin tone."""
    d = rng.standard_normal((n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.5  # mostly from the camera side (+z towards the viewer)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    warm = rng.uniform(0.85, 1.15, (n, 3))
    amb_share = rng.uniform(0.05, 0.15)
    total = rng.uniform(*power)
    share = rng.dirichlet(np.full(n, 2.0)) * (1 - amb_share) * total
    col = warm * share[:, None]
    amb = np.full(3, amb_share * total)
    return d, col, amb


def shade(albedo, micronormal, specular, normal, view, lights, *, roughness: float = 0.35,
          f0: float = 0.028, gamma: float = 2.2) -> np.ndarray:
    """Per-pixel shading.  All image inputs are [..., C] arrays over the same pixels:
    albedo 3, micronormal 3 (encoded, tangent space), specular 1, normal 3 (geometric, world,
    unit), view 3 (unit, surface → eye).  ``lights`` = (dirs [n,3], colours [n,3], ambient [3]).
    Returns RGB in [0, 1]."""
    N = np.asarray(normal, np.float64)
    up = np.where(np.abs(N[..., 1:2]) < 0.99, np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    T = np.cross(up, N)
    T /= np.linalg.norm(T, axis=-1, keepdims=True)
    B = np.cross(N, T)
    m = np.asarray(micronormal, np.float64) * 2 - 1
    n = T * m[..., :1] + B * m[..., 1:2] + N * m[..., 2:3]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    V = np.asarray(view, np.float64)
    nv = np.clip((n * V).sum(-1, keepdims=True), 1e-4, 1)
    a2 = roughness ** 4  # α = roughness², GGX uses α²
    k = (roughness + 1) ** 2 / 8
    dirs, cols, amb = lights
    out = np.asarray(albedo, np.float64) * amb
    for L, c in zip(dirs, cols):
        nl = np.clip((n * L).sum(-1, keepdims=True), 0, 1)
        H = L + V
        H /= np.linalg.norm(H, axis=-1, keepdims=True)
        nh = np.clip((n * H).sum(-1, keepdims=True), 0, 1)
        vh = np.clip((V * H).sum(-1, keepdims=True), 0, 1)
        D = a2 / (np.pi * (nh * nh * (a2 - 1) + 1) ** 2)
        G = (nv / (nv * (1 - k) + k)) * (nl / (nl * (1 - k) + k))
        F = f0 + (1 - f0) * (1 - vh) ** 5
        spec = D * G * F / (4 * nv * np.clip(nl, 1e-4, 1))
        out = out + c * nl * (np.asarray(albedo) + np.asarray(specular) * spec * np.pi)
    return np.clip(out, 0, 1) ** (1 / gamma)


def sample_uv_map(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a UV-space map [R, R, C] (row 0 is v = 1, as geoface textures) at
    ``uv`` [k, 2] in [0, 1]."""
    R = img.shape[0]
    x = np.clip(uv[:, 0] * R - 0.5, 0, R - 1)
    y = np.clip((1 - uv[:, 1]) * R - 0.5, 0, R - 1)
    x0, y0 = np.minimum(x.astype(np.int64), R - 2), np.minimum(y.astype(np.int64), R - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx) * (1 - fy)
            + (img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx) * fy)


def eye_albedo(cos_axis: np.ndarray, iris: np.ndarray, pupil_deg: float = 12.0, iris_deg: float = 30.0) -> np.ndarray:
    """Albedo [k, 3] of an eyeball at points ``cos_axis`` [k] (cosine of the angle between the
    point's direction from the eyeball's centre and its gaze): a black pupil, the ``iris``
    colour with a dark limbal ring at its rim, a white sclera reddening towards the back."""
    c = np.asarray(cos_axis, np.float64)[:, None]
    ang = np.degrees(np.arccos(np.clip(c, -1, 1)))
    sclera = np.array([0.80, 0.76, 0.72]) * (1 - 0.15 * np.clip((ang - 40) / 50, 0, 1)) + np.array([0.05, 0, 0]) * np.clip((ang - 50) / 40, 0, 1)
    ring = np.clip((ang - (iris_deg - 5)) / 5, 0, 1)  # limbal ring darkening over the iris's outer 5°
    iris_c = np.asarray(iris, np.float64)[None] * (1 - 0.6 * ring) * (0.8 + 0.4 * np.clip(ang / iris_deg, 0, 1))
    out = np.where(ang < iris_deg, iris_c, sclera)
    return np.where(ang < pupil_deg, 0.02, out)


def render_skin_sample(V, F, UV, maps: SkinMaps, camera, lights, *, normals=None,
                       background: float = 0.0, eyes: dict | None = None, solids=()) -> dict:
    """Render one training tuple of the texture model from a mesh with UVs.

    ``eyes`` (optional) shades parts that are not skin: ``{"eyeball": bool [n], "cos": [n]
    (see :func:`eye_albedo`), "iris": [3], "socket": bool [n]}``; a pixel whose triangle has an
    eyeball vertex gets :func:`eye_albedo` (wet: specular 0.9, flat micronormal), one with a
    socket vertex the pink of the inner eyelid.  Their pixels stay in ``mask`` (the caller
    decides what counts as skin).

    Returns float32 image-space arrays in [0, 1]: ``photo`` [H,W,3] (shaded, see :func:`shade`),
    ``maps`` [H,W,7] (albedo, micronormal, specular looked up through the pixel's UV),
    ``uv`` [H,W,2], ``normal`` [H,W,3] (camera-space geometric normal, encoded n/2 + ½),
    ``mask`` [H,W] bool (pixels the mesh covers) and ``face`` [H,W] (the triangle seen, -1 for none)."""
    from geoface.nn.mesh_render import rasterize_mesh

    V, F, UV = np.asarray(V, np.float64), np.asarray(F, np.int64), np.asarray(UV, np.float64)
    if normals is None:
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        normals = np.zeros_like(V)
        for c in range(3):
            np.add.at(normals, F[:, c], fn)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    face, bary, _ = rasterize_mesh(V, F, camera)
    H, W = face.shape
    m = face >= 0
    fi, b = face[m], bary[m]
    tri = F[fi]
    interp = lambda A: (A[tri] * b[..., None]).sum(1)  # noqa: E731
    uv = np.clip(interp(UV), 0, 1)
    P = interp(V)
    N = interp(normals)
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
    view = np.asarray(camera.center, np.float64)[None] - P
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    N = np.where((N * view).sum(1, keepdims=True) < 0, -N, N)  # back-facing interpolation at silhouettes
    stack = maps.stack()
    px = sample_uv_map(stack, uv)
    if eyes is not None:
        flat = np.array([0.5, 0.5, 1.0])
        sock = np.asarray(eyes.get("socket", np.zeros(len(V), bool)))[tri].any(1)
        px[sock] = np.r_[0.55, 0.30, 0.27, flat, 0.6]
        ball = np.asarray(eyes["eyeball"])[tri].any(1)
        if ball.any():
            c = (np.asarray(eyes["cos"], np.float64)[tri[ball]] * b[ball]).sum(1)
            px[ball] = np.concatenate([eye_albedo(c, eyes["iris"]), np.broadcast_to(flat, (len(c), 3)),
                                       np.full((len(c), 1), 0.9)], 1)
    for flags, albedo, spec in solids:
        hit = np.asarray(flags, bool)[tri].any(1)
        px[hit] = np.r_[np.asarray(albedo, np.float64), 0.5, 0.5, 1.0, float(spec)]
    rgb = shade(px[:, 0:3], px[:, 3:6], px[:, 6:7], N, view, lights)
    Ncam = N @ np.asarray(camera.R, np.float64).T
    out = {"photo": np.full((H, W, 3), background, np.float32), "maps": np.zeros((H, W, 7), np.float32),
           "uv": np.zeros((H, W, 2), np.float32), "normal": np.zeros((H, W, 3), np.float32), "mask": m,
           "face": face}
    out["photo"][m] = rgb
    out["maps"][m] = px
    out["uv"][m] = uv
    out["normal"][m] = Ncam * 0.5 + 0.5
    return out


def unweld_uv(V, F, UV, FUV, *, with_source: bool = False):
    """A mesh with per-corner texture coordinates (``FUV`` into ``UV``) as one with a UV per
    vertex: a vertex is split where its corners have different UVs (along the seams).  Returns
    ``(V', F', UV')`` and, ``with_source``, the input vertex of each new one."""
    F, FUV = np.asarray(F, np.int64), np.asarray(FUV, np.int64)
    pairs = np.stack([F.ravel(), FUV.ravel()], 1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    out = np.asarray(V)[uniq[:, 0]], inv.reshape(F.shape), np.asarray(UV)[uniq[:, 1]]
    return (*out, uniq[:, 0]) if with_source else out


_ICT_CACHE: dict = {}


def ict_source(map_res: int):
    """The ICT model and its face-tile regions at ``map_res`` (once per process)."""
    if map_res not in _ICT_CACHE:
        from geoface.synth.ict import load_ict_model

        from .regions import ict_uv_regions
        model = _ICT_CACHE.get("model") or load_ict_model()
        _ICT_CACHE["model"] = model
        _ICT_CACHE[map_res] = ict_uv_regions(map_res, model.head(identity=np.zeros(model.n_identities)))
    return _ICT_CACHE["model"], _ICT_CACHE[map_res]


IRIS = np.array([[0.30, 0.16, 0.06], [0.18, 0.09, 0.04], [0.25, 0.35, 0.45], [0.28, 0.33, 0.18], [0.10, 0.06, 0.03]])


def ict_eyes(neutral_V, src, head, rng) -> dict:
    """The ``eyes`` argument of :func:`render_skin_sample` for an unwelded ICT head: per vertex,
    eyeball / socket flags and the cosine to the gaze axis (+z, measured on the person's neutral
    head, so a look blendshape turns the pattern with the eyeball)."""
    lab = head.labels[src]
    ball = lab == 7
    cos = np.zeros(len(src))
    for side in (-1, 1):
        sel = ball & (np.sign(neutral_V[src, 0]) == side)
        P = neutral_V[src[sel]]
        A = np.c_[2 * P, np.ones(len(P))]  # sphere fit: |p|² = 2 p·c + (r² − |c|²)
        c = np.linalg.lstsq(A, (P ** 2).sum(1), rcond=None)[0][:3]
        d = P - c
        cos[sel] = d[:, 2] / np.linalg.norm(d, axis=1)
    return {"eyeball": ball, "socket": lab == 4, "cos": cos, "iris": IRIS[rng.integers(len(IRIS))] * rng.uniform(0.8, 1.2)}


def pixel_average(s: dict, ss: int, gamma: float = 2.2) -> dict:
    """A sample rendered at ``ss``× the resolution → what a camera's pixels integrate: the
    mean of each ``ss``×``ss`` block of light (the photo averaged in linear light, then
    re-encoded), of the maps, UVs and normals (unit vectors renormalised); a pixel is in the
    mask when all of its block is.  Returns the keys photo, maps, uv, normal, mask."""
    def avg(a):
        H, W = a.shape[:2]
        return a.reshape(H // ss, ss, W // ss, ss, *a.shape[2:]).mean((1, 3))

    def unit(enc):  # encoded unit vectors n/2 + ½ → their mean direction, encoded
        v = avg(enc.astype(np.float64) * 2 - 1)
        return (v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12) * 0.5 + 0.5).astype(np.float32)

    out = {"photo": (avg(s["photo"].astype(np.float64) ** gamma) ** (1 / gamma)).astype(np.float32),
           "uv": avg(s["uv"]).astype(np.float32), "normal": unit(s["normal"]),
           "mask": avg(s["mask"].astype(np.float32)) > 0.999}
    maps = avg(s["maps"]).astype(np.float32)
    maps[..., 3:6] = unit(s["maps"][..., 3:6])
    out["maps"] = maps
    for k in ("maps", "uv", "normal"):
        out[k][~out["mask"]] = 0.0
    return out


