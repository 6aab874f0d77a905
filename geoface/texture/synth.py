"""Synthetic training data of the 4K-texture model: :func:`make_texture_dataset` writes
(photo, maps, UV, normal, mask, landmarks) samples of procedural or ICT-FaceKit heads with
regional skin, rendered under random lights.

The skin maps and their renderer live in :mod:`geoface.skin.render` (also used by the avatar
captures); their names stay importable from here.
"""
from __future__ import annotations

import numpy as np

from geoface.skin.render import *  # noqa: F401,F403  (the renderer, kept importable from here)
from geoface.skin.render import (IRIS, ict_eyes, ict_source, pixel_average, random_lights,  # noqa: F401
                                 render_skin_sample, skin_maps, unweld_uv, sample_uv_map, uv_grid_v, periodic_noise)

from ..errors import LearnError


def _write_texture_sample(path, i: int, seed: int, res: int, map_res: int, vertices: int, head_source: str = "procedural",
                          supersample: int = 1) -> None:
    from geoface.camera import look_at
    from geoface.synth import procedural_head

    from .model import save_sample

    rng = np.random.default_rng([seed, i])
    eyes = None
    if head_source == "ict":  # a random person with a random expression, skin by region, eyes
        from geoface.synth.ict import random_expression
        model, regions = ict_source(map_res)
        ident = rng.standard_normal(model.n_identities)
        expr = random_expression(rng, model.expression_names, count=2, strength=0.6)
        parts = ("skin", "eyes")
        head = model.head(identity=ident, expression=expr, parts=parts)
        V, F, UV, src = unweld_uv(head.V, head.F, head.UV, head.FUV, with_source=True)
        skin = head.labels[src][F].max(1) <= 2  # a triangle's region (as the model's polygons): skin
        eyes = ict_eyes(model.shape(ident, parts=parts), src, head, rng)
        P = head.V[head.labels == 0]  # the narrow face (brows to chin)
        scale = float(np.ptp(P[:, 1])) * 0.8  # a portrait: the face fills most of the frame
        centre = P.mean(0)
    else:
        head = procedural_head(vertices, seed=int(rng.integers(1 << 31)))
        V, F, UV, skin, scale, regions = head.V, head.F, head.UV, None, 0.16, None
        centre = head.V[head.face_mask].mean(0)
    yaw, pitch = np.radians(rng.uniform(-20, 20)), np.radians(rng.uniform(-10, 10))
    dist = rng.uniform(2.5, 3.0) * scale
    eye = centre + dist * np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    ss = int(supersample)
    cam = look_at(eye, centre + rng.normal(0, 0.03125 * scale, 3), width=res * ss, height=res * ss, fov_y_deg=30)
    maps = skin_maps(map_res, seed=int(rng.integers(1 << 31)), regions=regions)
    s = render_skin_sample(V, F, UV, maps, cam, random_lights(rng, int(rng.integers(2, 5))), eyes=eyes)
    if skin is not None:  # the face tile's skin only: not the eyes, nor other tiles (the back of the head, the ears)
        in_tile = ((UV >= 0) & (UV <= 1)).all(1)
        s["mask"] &= skin[np.maximum(s["face"], 0)] & in_tile[F[np.maximum(s["face"], 0)]].all(-1)
    if ss > 1:
        s = pixel_average(s, ss)
    lm = cam.project(head.V[head.landmarks])[0] / ss if head_source == "ict" else None  # the 68 points, as a detector gives them
    save_sample(path, s["photo"], s["maps"], s["uv"], s["normal"], s["mask"], landmarks=lm)


def make_texture_dataset(out_dir, count: int = 8, res: int = 512, map_res: int | None = None, *,
                         seed: int = 0, vertices: int = 20000, workers: int = 1,
                         quiet: bool | None = None, head_source: str = "procedural", supersample: int = 2) -> list:
    """Write ``count`` texture-model samples (``sample_XXXX.npz``, see
    :func:`geoface.texture.model.save_sample`) of procedural skin on heads, each from a
    jittered near-frontal camera under random lights.  ``head_source``: ``"procedural"`` (our
    head, stationary skin) or ``"ict"`` (ICT-FaceKit people with random expressions, skin by
    facial region on the model's UV layout; pixels outside its face tile are masked out).
    ``supersample``: each pixel is the average of s×s rendered ones (:func:`pixel_average`), as a
    camera integrates light over its pixels; 1 point-samples the maps (aliased detail, which no
    model can recover from the photo).  ``map_res`` (default: ``res``,
    at least 1024) is the UV-map resolution.  Sample ``i`` depends only on (``seed``, ``i``),
    so ``workers`` > 1 (a process pool) writes the same files.  Returns the paths; existing
    samples are kept (resumable)."""
    from concurrent.futures import ProcessPoolExecutor
    from pathlib import Path

    from geoface.progress import progress

    if count < 1 or not 32 <= res <= 8192:
        raise LearnError(f"need count >= 1 and res in 32..8192; got count={count}, res={res}")
    map_res = int(map_res or max(res, 1024))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"sample_{i:04d}.npz" for i in range(count)]
    todo = [i for i in range(count) if not paths[i].exists()]
    if head_source not in ("procedural", "ict"):
        raise LearnError(f"head_source must be 'procedural' or 'ict'; got {head_source!r}")
    if supersample not in (1, 2, 3, 4):
        raise LearnError(f"supersample must be 1..4; got {supersample}")
    args = [(paths[i], i, seed, res, map_res, vertices, head_source, supersample) for i in todo]
    if workers > 1 and len(todo) > 1:
        import multiprocessing as mp
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as ex:
            futs = [ex.submit(_write_texture_sample, *a) for a in args]
            for f in progress(futs, "texture samples", total=len(futs), quiet=quiet):
                f.result()
    else:
        for a in progress(args, "texture samples", total=len(args), quiet=quiet):
            _write_texture_sample(*a)
    return paths
