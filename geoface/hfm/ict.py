"""Synthetic HMD captures of real heads: a person of the ICT-FaceKit model (built from scans of
real people, :mod:`geoface.synth.ict`) talking and emoting, lit, with eyes, teeth and a mouth.

What :func:`make_ict_hmd` renders, frame by frame:

* **the person**: identity weights of the model (``identity``: a row of N(0, 1) weights drawn
  from the seed, or given), skin maps with facial regions on the model's UV layout (lips, brows,
  eyelids, pores, forehead lines, stubble, freckles; :func:`geoface.skin.render.skin_maps`),
  eyes (iris, pupil, sclera), teeth, gums, tongue and the mouth's interior;
* **expressions** as ARKit weight curves (:func:`arkit_curves`): speech-like jaw and lip motion
  (syllables in phrases, vowels that round the lips), emotions that couple upper and lower face
  (surprise: brows up, eyes wide, jaw open; smile: cheeks and lower lids up; anger: brows down,
  frown, sneer) and blinks.  The registration and the usage video are *different* sequences
  (other phrases, emotions and blinks), not two halves of one; the registration video may open
  with a range of motion (``rom``: each emotion in turn at full weight);
* **lighting**: Lambert + GGX specular (:func:`geoface.skin.render.shade`) under lights that
  stay fixed in the world while the head turns, so shading changes with the pose;
* **motion**: a rigid head motion (yaw, pitch, roll, translation) about the neck and a small
  per-frame camera shake (both in ``head_poses.npz``, which holds the exact pose relative to the
  nominal camera of ``camera.json``);
* **the headset** in the usage video (``hmd_masks/``), with ``gt/`` (the same frames without
  it) and ``gt_static_upper/`` (the upper-face expression at rest, see :mod:`hfm_data`).

Registration frame 0 is the person at rest in the canonical pose, which is ``head.ply`` (a
decimated copy of the rendered mesh with vertex colours, for the Gaussians' initialisation).
``landmarks.json`` holds the 68 iBUG points (:data:`geoface.avatar.capture.IBUG68_NAMES`) that a
face tracker gives; in the usage video only those below the headset (jaw, nose base, mouth).
Units are metres.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geoface.errors import AvatarError
from geoface.images import save_image
from geoface.capture import write_camera, write_head_poses, write_landmarks, write_meta
from geoface.avatar.ict import ICTPerson, arkit_curves, head_motion, is_upper_blendshape

__all__ = ["make_ict_hmd"]


def make_ict_hmd(out, *, frames: int = 200, usage_frames: int | None = None, res: int = 128, identity=None,
                 seed: int = 0, motion: float = 1.0, jitter: float = 1.0, fps: float = 25.0, map_res: int = 512,
                 gaussians: int = 12000, supersample: int = 2, rom: float = 0.0,
                 quiet: bool | None = None) -> tuple[Path, Path]:
    """Write ``out/registration`` (``frames`` frames) and ``out/usage`` (``usage_frames``, default a
    quarter of ``frames``) of one ICT-FaceKit person (format: :mod:`geoface.hfm.data`; what
    is rendered: the module doc); returns both folders.

    ``identity``: the model's identity weights (a sequence of up to 100 numbers) or None (drawn
    from ``seed``); ``gaussians``: vertices of ``head.ply``, the decimated canonical head; ``rom``:
    seconds of the registration video that go through the emotions at full weight first (a
    range of motion, :func:`arkit_curves`; 0: none, the expressions are free throughout)."""
    from geoface.mesh.io import save_mesh
    from geoface.progress import progress
    from geoface.avatar.capture import IBUG68_NAMES, IBUG68_LOWER, euler_rotation

    usage_frames = max(5, frames // 4) if usage_frames is None else int(usage_frames)
    if frames < 5 or usage_frames < 1:
        raise AvatarError(f"need frames >= 5 and usage_frames >= 1; got {frames}, {usage_frames}")
    if not (0 <= rom and 0.2 + rom <= frames / fps):
        raise AvatarError(f"the range of motion ({rom} s) must fit in the registration video ({frames / fps - 0.2:.1f} s after "
                         "its first 0.2 s)")
    out = Path(out)
    rng = np.random.default_rng([seed, 7101])
    person = ICTPerson(rng, identity=identity, res=res, map_res=map_res, supersample=supersample)
    ident, lmk, cam, pivot, y_split = person.ident, person.rest.landmarks, person.cam, person.pivot, person.y_split
    render = person.render

    n_all = frames + usage_frames
    rng_r, rng_u = (np.random.default_rng([seed, 7102, k]) for k in range(2))
    seqs = {"registration": (arkit_curves(frames, rng_r, fps=fps, rom=rom), head_motion(frames, rng_r, fps, motion, jitter, 10)),
            "usage": (arkit_curves(usage_frames, rng_u, fps=fps), head_motion(usage_frames, rng_u, fps, motion, jitter, 0))}
    # registration frame 0: the person at rest in the canonical pose (head.ply)
    seqs["registration"][0][0] = {k: 0.0 for k in seqs["registration"][0][0]}
    dirs = {"registration": out / "registration", "usage": out / "usage"}
    for which, d in dirs.items():
        subs = ("frames", "masks") + (("hmd_masks", "gt", "gt_static_upper") if which == "usage" else ())
        for sub in subs:
            (d / sub).mkdir(parents=True, exist_ok=True)
    it = progress(range(n_all), "rendering ICT HMD videos", total=n_all, quiet=quiet)
    jobs = [("registration", k) for k in range(frames)] + [("usage", k) for k in range(usage_frames)]
    poses = {w: ([], []) for w in dirs}
    lm_pts = {w: [] for w in dirs}
    log = {w: [] for w in dirs}
    lower_idx = list(IBUG68_LOWER)
    for _, (which, k) in zip(it, jobs):
        exprs, (ang, tr) = seqs[which]
        R = euler_rotation(*ang[k])
        d = dirs[which]
        name = f"{k:06d}.png"
        V, rgb, alpha, hmd = render(exprs[k], R, tr[k], which == "usage")
        uv, _ = cam.project(V[lmk])
        uv = np.asarray(uv)
        lm_pts[which].append((uv if which == "registration" else uv[lower_idx]).tolist())
        poses[which][0].append(R)
        poses[which][1].append(tr[k])
        log[which].append({"frame": k, "expression": {n: round(v, 4) for n, v in exprs[k].items() if v > 1e-4},
                           "yaw_pitch_roll_deg": np.degrees(ang[k]).tolist(), "translation": tr[k].tolist()})
        save_image(d / "frames" / name, rgb)
        save_image(d / "masks" / name, (alpha > 0.5).astype(np.uint8) * 255)
        if which == "usage":
            save_image(d / "hmd_masks" / name, hmd.astype(np.uint8) * 255)
            _, g, _, _ = render(exprs[k], R, tr[k], False)
            save_image(d / "gt" / name, g)
            still = {n: (0.0 if is_upper_blendshape(n) else v) for n, v in exprs[k].items()}
            _, g, _, _ = render(still, R, tr[k], False)
            save_image(d / "gt_static_upper" / name, g)
    for which, d in dirs.items():
        names = list(IBUG68_NAMES) if which == "registration" else [IBUG68_NAMES[i] for i in lower_idx]
        write_landmarks(d, lm_pts[which], names)
        write_head_poses(d, np.stack(poses[which][0]), np.stack(poses[which][1]), pivot)
        write_camera(d, cam)
        write_meta(d, {
            "y_split": y_split, "up": [0, 1, 0], "source": "ICT-FaceKit", "seed": seed, "fps": fps,
            "identity": [round(float(x), 5) for x in ident], "rom_seconds": rom if which == "registration" else 0.0,
            "lights": [a.tolist() for a in person.lights],
            "upper_blendshapes": sorted(n for n in exprs[0] if is_upper_blendshape(n)), "frames": log[which]})
    Vi, Fi, Ci = person.init_mesh(gaussians)
    save_mesh(dirs["registration"] / "head.ply", V=Vi, F=Fi, colors=Ci)
    return dirs["registration"], dirs["usage"]
