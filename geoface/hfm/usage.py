"""Using a registered HFM-GS model: removing the headset from video, and its evaluation
(:mod:`geoface.hfm`)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from geoface.errors import AvatarError
from geoface.hfm.data import frame_input
from geoface.hfm.model import HFMModel
from geoface.hfm.train import frame_pose


# ----------------------------------------------------------------------------- usage
POSE_SOURCES = ("auto", "file", "track", "landmarks", "image")


@torch.no_grad()
def usage_poses(model: HFMModel, video, source: str = "auto") -> tuple[tuple | None, str]:
    """The head pose of each usage frame and where it came from, one of:

    * ``"file"`` — the folder's ``head_poses.npz`` (a headset's own tracking in the camera's frame);
    * ``"track"`` — the same file as a tracker made it from the pixels (the head of the
      registration's identity tracked below the headset: what ``hmd remove MODEL VIDEO`` does,
      :func:`geoface.avatar.clip.capture_clip` with ``headset``), then aligned with the image as
      the landmarks' poses are (``cfg.pose_align``);
    * ``"landmarks"`` — fitted to the frame's landmarks below the headset that move little with
      expressions (nose base, the jaw line's ends: :data:`~geoface.avatar.head_pose.LOWER_RIGID_NAMES`,
      or the 8 of them in :data:`~geoface.avatar.head_pose.LOWER_STABLE_NAMES` with ``cfg.usage_landmarks``
      "stable"; every landmark the registration placed on the head for other names), by the robust PnP of
      :mod:`geoface.avatar.head_pose`, starting from the pose the model reads from the first crop,
      then corrected into the registration poses' frame by the model's ``pose_calibration`` when
      it has one and the video has the lower-face landmarks it reads; with ``cfg.headset_pose``
      and the video's ``hmd_masks``, then moved by what the lower face's expressions do to the
      headset silhouette's place (:mod:`geoface.hfm.headset_pose`: a broad smile that the
      registration never showed tilts the calibrated pose; the headset, rigid with the head, does
      not smile) — source ``"landmarks+headset"``; with ``cfg.pose_align`` steps and the video's
      ``hmd_masks``, then aligned with the image (:func:`~geoface.hfm.align.align_poses`:
      each frame's pose turned so that the avatar's render matches the pixels the headset leaves
      visible) — ``"+image"`` added to the source;
    * ``"image"`` — read from each lower-face crop by the model (None is returned: the model does it
      per frame);
    * ``"auto"`` — the file, else the landmarks (at least 4 such points), else the image.

    Returns ``((R [T, 3, 3], t [T, 3], pivot [3]) or None, source)``."""
    from geoface.avatar.head_pose import apply_lower_calibration, calibration_scores

    if source not in POSE_SOURCES:
        raise AvatarError(f"poses must be one of {POSE_SOURCES}; got {source!r}")
    if source in ("file", "track") or (source == "auto" and video.poses is not None):
        if video.poses is None:
            raise AvatarError(f"poses {source!r}: the usage folder has no head_poses.npz")
        if source != "track":
            return video.poses, "file"
        return _aligned(model, video, video.poses, "track")
    if source == "image":
        return None, "image"
    lower = _lower_fit(model, video, need=source == "landmarks")
    if lower is None:
        return None, "image"
    R, t, piv, P, known, cal, w = lower
    got = None  # in the registration poses' frame
    if cal is not None:
        got = apply_lower_calibration(cal, video.camera, known, video.landmarks, video.names, R, t, piv)
        Z = calibration_scores(cal, video.camera, known, video.landmarks, video.names, R, t, piv)
        _warn_beyond(_coverage(cal, Z))
    pose, source = ((R, t, piv) if got is None else (*got, piv)), "landmarks"
    anchor = known.get("nose_bridge_0")  # where a headset sits
    if got is not None and model.cfg.headset_pose and video.hmd_masks is not None and anchor is not None:
        from geoface.hfm.headset_pose import headset_centroids, headset_components, headset_poses

        cen = headset_centroids(video.hmd_masks)
        if headset_components(int(np.isfinite(cen).all(1).sum()), len(cal["basis"])) >= 1:  # enough whole silhouettes
            Rh, th, _ = headset_poses(video.camera, *got, piv, P, cen, anchor, Z, weights=w,
                                      ridge=model.cfg.headset_pose_ridge)
            pose, source = (Rh, th, piv), "landmarks+headset"
    return _aligned(model, video, pose, source)


def _aligned(model: HFMModel, video, pose, source: str):
    """``(pose, source)`` aligned with the image by the avatar (:func:`~geoface.hfm.align.align_poses`)
    when the model asks for it (``cfg.pose_align`` steps) and the video has headset masks."""
    if model.cfg.pose_align and video.hmd_masks is not None:
        from geoface.hfm.align import align_poses

        with torch.enable_grad():
            pose = align_poses(model, video, pose, steps=model.cfg.pose_align,
                               translation=model.cfg.pose_align_translation)
        source += "+image"
    return pose, source


#: share of the usage frames beyond the registration's expressions at which :func:`usage_poses` warns
BEYOND_WARN = 0.25


@torch.no_grad()
def _lower_fit(model: HFMModel, video, need: bool = False):
    """The usage poses fitted to the landmarks below the headset, before any correction:
    (R [T, 3, 3], t [T, 3], pivot, canonical points [K, 3], name → canonical point, the model's
    calibration when it reads these landmarks else None, the fit's weights or None); None when fewer
    than 4 of the video's landmarks are known on the head (``need``: raise instead)."""
    from geoface.avatar.head_pose import repivot, solve_poses

    lm = getattr(model, "landmarks3d", None)
    use = []
    if lm is not None:
        known = dict(zip(lm["names"], lm["points"]))
        fit_set = model.cfg.usage_fit_names
        rigid = [n for n in video.names if n in fit_set and n in known]
        use = rigid if rigid else [n for n in video.names if n in known]
    if need and len(use) < 4:
        raise AvatarError(f"poses 'landmarks': {len(use)} of the usage landmarks are known on the head (need 4; "
                         "the model keeps the registration landmarks since this version)")
    if len(use) < 4:
        return None
    P = np.array([known[n] for n in use])
    idx = [video.names.index(n) for n in use]
    piv = P.mean(0)
    init = None
    if model.predicts_head_pose:  # start from the pose the crop says
        boxes = video.boxes()
        q = model.head_pose_params(model.encoder(*frame_input(video, 0, model.cfg.crop, boxes)))[0]
        R0, t0, c = (a.double().cpu().numpy() for a in model.head_pose_from_params(q))
        init = (R0, repivot(R0, t0, c, piv))
    cal = getattr(model, "pose_calibration", None)
    calibrated = cal is not None and sorted(cal["fit_names"]) == sorted(use)
    w = None
    if calibrated and "fit_weights" in cal:  # the weights the calibration's poses were fitted with
        weight_of = dict(zip(cal["fit_names"], cal["fit_weights"]))
        w = [weight_of[n] for n in use]
    fit = solve_poses(video.camera, P, video.landmarks[:, idx], piv, init=init, weights=w)
    return fit["R"], fit["t"], piv, P, known, cal if calibrated else None, w


def expression_coverage(model: HFMModel, video) -> dict | None:
    """How far the usage video's lower-face expressions lie beyond those of the registration video
    the model's pose calibration learned from (:func:`~geoface.avatar.head_pose.expression_reach`):
    ``expression_beyond`` = the share of frames beyond the farthest registration frame,
    ``expression_reach_median`` / ``_max`` = their distances in units of it.  Beyond it the
    calibration extrapolates, and the calibrated usage poses (and with them the restored upper
    face) may be off: a registration video that goes through the person's expressions (a range
    of motion) covers them.  None without a calibration that keeps its spreads (one learned from
    fewer than four registration frames per component does not), or without the
    lower-face landmarks it reads."""
    from geoface.avatar.head_pose import calibration_scores

    lower = _lower_fit(model, video)
    if lower is None or lower[5] is None:
        return None
    R, t, piv, _, known, cal, _ = lower
    return _coverage(cal, calibration_scores(cal, video.camera, known, video.landmarks, video.names, R, t, piv))


def _coverage(cal: dict, Z) -> dict | None:
    """:func:`expression_coverage`'s figures from the calibration ``cal`` and the frames' scores ``Z``."""
    from geoface.avatar.head_pose import expression_reach

    r = expression_reach(cal, Z)
    if r is None:
        return None
    return {"expression_beyond": float((r > 1).mean()), "expression_reach_median": float(np.median(r)),
            "expression_reach_max": float(r.max())}


def _warn_beyond(cov: dict | None) -> None:
    """A :class:`~geoface.errors.GeofaceWarning` when much of the usage video is beyond the registration's expressions."""
    if cov is not None and cov["expression_beyond"] >= BEYOND_WARN:
        import warnings

        from geoface.errors import GeofaceWarning

        warnings.warn(f"{cov['expression_beyond']:.0%} of the usage frames show lower-face expressions beyond any the "
                      f"registration video showed (up to {cov['expression_reach_max']:.1f} times as far from its mean "
                      "face): the calibration of the usage poses extrapolates there and the restored upper face may sit "
                      "off; register with a video that goes through the person's expressions",
                      GeofaceWarning, stacklevel=4)  # the caller of usage_poses (under no_grad)


def remove_hmd(model: HFMModel, video, *, out_dir=None, camera=None, composite: bool = True, poses: str = "auto",
               with_source: bool = False):
    """Restore every frame of ``video`` (an :class:`HMDVideo`): render the avatar driven by the
    lower-face crop, in the head pose that ``poses`` says (:func:`usage_poses`); where
    ``video.hmd_masks`` is known, paste the rendering into the occluded region only
    (``composite``). Streams frame by frame; returns (renders [T, H, W, 3] float32, per-frame
    seconds, including the pose fit), and where the poses came from (:func:`usage_poses`'s
    source) with ``with_source``. Writes ``out_dir/frames/*.png`` when given (each file complete
    or absent)."""
    out = _remove(model, video, out_dir, camera, composite, poses)
    return out if with_source else out[:2]


@torch.no_grad()
def _remove(model, video, out_dir, camera, composite, poses):
    """:func:`remove_hmd`, also returning where the poses came from."""
    from dataclasses import replace

    from geoface.avatar.capture import write_frame
    from geoface.splat.rasterizer import rasterize

    t0 = time.perf_counter()
    pose, source = usage_poses(model, video, poses)
    fit_s = (time.perf_counter() - t0) / max(len(video), 1)
    video = replace(video, poses=pose)
    cam = camera or video.camera
    out = Path(out_dir) if out_dir is not None else None
    renders, times = [], []
    bg = torch.zeros(3)
    boxes = video.boxes()
    for t in range(len(video)):
        t0 = time.perf_counter()
        rgb = rasterize(model(*frame_input(video, t, model.cfg.crop, boxes), frame_pose(video, t)), cam,
                        background=bg)[0].clamp(0, 1).numpy()
        times.append(time.perf_counter() - t0 + fit_s)
        renders.append(rgb)
        if out is not None:
            img = rgb
            if composite and video.hmd_masks is not None:
                img = np.where(video.hmd_masks[t][..., None], rgb, video.frames[t])
            write_frame(out, t, img)
    return np.stack(renders), np.asarray(times), source


@torch.no_grad()
def expression_motion(model: HFMModel, video) -> dict:
    """How far the crop moves the Gaussians: per Gaussian, the RMS distance of its deformed
    centre (before the tracked head pose) from its mean over the frames of ``video``; averaged
    over the upper and the lower set, in millimetres (scene units are metres). Near zero means
    the avatar ignores the lower face (a collapsed encoder or dead deformation networks)."""
    boxes = video.boxes()
    P = torch.stack([model(*frame_input(video, t, model.cfg.crop, boxes), read_pose=False).means
                     for t in range(len(video))])
    rms = (P - P.mean(0)).pow(2).sum(-1).mean(0).sqrt() * 1000
    up = model.upper_mask()
    return {"upper_motion_mm": float(rms[up].mean()) if bool(up.any()) else 0.0,
            "lower_motion_mm": float(rms[~up].mean()) if bool((~up).any()) else 0.0}


EXPRESSION_TAU = 0.02     # a pixel belongs to the expression region where it changes by more than this
EXPRESSION_MIN_PIXELS = 10
OUTLINE_PX = 1            # the occluded region's outline: face pixels this close to the face's edge


def evaluate_hmd(model: HFMModel, video, poses: str = "auto") -> dict:
    """PSNR/SSIM of the renders against ``video.gt`` on the whole face (foreground) and in the
    region the headset hides (``video.hmd_masks_true`` when known, else ``video.hmd_masks``); FPS
    of the whole per-frame path (crop, encode, deform, render).

    Where the usage folder has ``gt_static_upper/`` (the synthetic videos: the same frames with
    brows and lids at rest), also the *expression region* of each frame: the occluded face pixels
    that the upper expression changes by more than ``EXPRESSION_TAU`` in some channel. On the
    synthetic head a render that is perfect except that it ignores the upper expression scores
    about 41 dB over the whole occluded region (most of it is forehead and lids at rest), so the
    occluded-region PSNR of a ~34 dB avatar mostly measures its static quality; ``psnr_expression``
    and ``ssim_expression`` score only what the upper expression changes (frames with at least
    ``EXPRESSION_MIN_PIXELS`` such pixels), and ``psnr_expression_rest`` is what the rest-pose
    frames themselves score there — an avatar must beat it to show it restored the expression.

    The occluded region is also split into its *outline* (``psnr_occluded_outline``: the face
    pixels within ``OUTLINE_PX`` of the face's edge in the ground truth — under a headset, the
    crown and the temples against the background, where a head placed a fraction of a pixel off
    costs most) and the rest (``psnr_occluded_interior``: brows, lids, forehead). With usage poses
    fitted to the landmarks, also how far the usage expressions lie beyond the registration's
    (:func:`expression_coverage`; ``expression_beyond`` etc.)."""
    if video.gt is None or video.hmd_masks is None:
        raise AvatarError("evaluation needs gt/ and hmd_masks/ in the usage folder")
    R, times, source = _remove(model, video, None, None, True, poses)
    out = hmd_metrics(R, video)
    out["poses"] = source
    if source.startswith("landmarks"):
        out.update(expression_coverage(model, video) or {})
    out.update(expression_motion(model, video))
    out.update(frames=len(video), fps=float(1.0 / np.median(times)), seconds_per_frame=float(np.median(times)))
    return out


def hmd_metrics(R: np.ndarray, video) -> dict:
    """The image metrics of :func:`evaluate_hmd` for renders ``R`` [T, H, W, 3] of ``video``."""
    from scipy.ndimage import binary_erosion

    from geoface.splat.fit import psnr, ssim_masked

    if video.gt is None or video.hmd_masks is None:
        raise AvatarError("evaluation needs gt/ and hmd_masks/ in the usage folder")
    if R.shape != video.gt.shape:
        raise AvatarError(f"renders {R.shape} do not match the usage frames {video.gt.shape}")
    face = video.gt.max(-1) > 0
    rest = video.gt_static_upper
    hidden = video.hmd_masks if video.hmd_masks_true is None else video.hmd_masks_true  # score where it truly hides
    rows = {"psnr_face": [], "ssim_face": [], "psnr_occluded": [], "ssim_occluded": [], "psnr_occluded_interior": [],
            "psnr_occluded_outline": []}
    if rest is not None:
        rows.update(psnr_expression=[], ssim_expression=[], psnr_expression_rest=[], expression_pixels=[])
    for t in range(len(video)):
        m, o = face[t], hidden[t] & face[t]
        rows["psnr_face"].append(psnr(R[t], video.gt[t], m))
        rows["psnr_occluded"].append(psnr(R[t], video.gt[t], o))
        rows["ssim_face"].append(ssim_masked(R[t], video.gt[t], m))
        rows["ssim_occluded"].append(ssim_masked(R[t], video.gt[t], o))
        edge = o & ~binary_erosion(m, iterations=OUTLINE_PX, border_value=1)
        for key, region in (("psnr_occluded_interior", o & ~edge), ("psnr_occluded_outline", edge)):
            rows[key].append(psnr(R[t], video.gt[t], region) if region.any() else float("nan"))
        if rest is not None:
            e = o & (np.abs(video.gt[t] - rest[t]).max(-1) > EXPRESSION_TAU)
            rows["expression_pixels"].append(float(e.sum()))
            if e.sum() >= EXPRESSION_MIN_PIXELS:
                rows["psnr_expression"].append(psnr(R[t], video.gt[t], e))
                rows["ssim_expression"].append(ssim_masked(R[t], video.gt[t], e))
                rows["psnr_expression_rest"].append(psnr(rest[t], video.gt[t], e))
    out = {k: float("nan") if np.isnan(v).all() else float(np.nanmean(v)) for k, v in rows.items()}  # all NaN: no figure
    if rest is not None:
        out["expression_frames"] = len(rows["psnr_expression"])
    return out


def drive_hfm(model: HFMModel, source, *, fps: float = 25.0):
    """:meth:`HFMModel.drive`: the avatar frame by frame, driven by the usage folder ``source``
    (each frame's lower-face crop; the folder's own frames shown beside)."""
    import json

    from geoface.avatar.model_dir import AvatarDrive, uint8_frames
    from geoface.hfm.data import load_video

    if source is None or not Path(source).is_dir():
        raise AvatarError(f"{source}: a headset-removal avatar is driven by a usage folder (`hmd synth` writes one)")
    source = Path(source)
    video = load_video(source)
    boxes = video.boxes()
    meta = json.loads((source / "meta.json").read_text(encoding="utf-8")) if (source / "meta.json").is_file() else {}

    def g(t):
        return model(*frame_input(video, t, model.cfg.crop, boxes), frame_pose(video, t))

    return AvatarDrive(len(video), float(meta.get("fps", fps)), f"the headset video in {source.name}", model.KIND, g,
                       uint8_frames(video.frames))

