"""A real clip becomes a capture: ``geoface capture VIDEO|FRAMES -o DIR``.

What a user has is a video of a person (or its frames). :func:`capture_clip` makes of it the
capture folder both avatars learn from (:mod:`geoface.capture`), with nothing from a renderer:

1. the frames decoded (and the sound, to ``audio.wav``, when the video has any, or ``audio``);
2. MediaPipe's face mesh on every frame (video mode): 468 points, the face detector's confidence;
3. a square crop that follows the face: each frame's face box (the 468 points' extent), its
   centre smoothed over time by a Gaussian of ``smooth_seconds`` (no jitter) and one side for the
   clip (``margin`` × the largest face, so the face stays whole when it comes closer); parts of the
   crop outside the picture are black; resampled to ``res`` × ``res``;
4. the person's mask on each crop (MediaPipe's selfie segmentation; soft edge kept) and the frame
   with its background removed (faded by the mask);
5. the ICT-FaceKit head tracked through the clip (:func:`geoface.track.head_track.fit_head_track`:
   one identity, per-frame expressions and pose, one focal length) on the crops' points;
6. written: ``frames/``, ``masks/``, ``landmarks.json`` (the iBUG 68) and ``landmarks_dense.npz``
   (the 468), ``camera.json`` (the focal length fitted, or ``focal`` given in the video's pixels;
   world = the tracked head's frame in the pose of frame 0), ``head_poses.npz`` (each frame's head
   relative to frame 0, about the neck), ``expressions.npz`` (the 53 ARKit weights),
   ``head.ply`` (the person's neutral ICT head, decimated to ``head_vertices``, with vertex colours
   taken from the frames where each vertex faces the camera), ``meta.json`` (fps, the crop boxes in
   the video's pixels, the ICT identity, the upper/lower split for HFM-GS, the fit's figures) and
   ``overlay.mp4``: the tracked head drawn over the frames, to watch that the track is right.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoface.errors import CaptureError

__all__ = ["capture_clip", "ClipCapture", "face_crops", "crop_frames", "head_colours", "overlay_frames", "capture_head",
           "write_overlay"]

log = logging.getLogger(__name__)

#: MediaPipe face-mesh points that bound the face (its outline)
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152, 148, 176, 149,
         150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)


@dataclass(frozen=True)
class ClipCapture:
    """What :func:`capture_clip` did: the folder, frames, frames with a face, fps, the crop's side
    (video pixels), the focal length (crop pixels), the fit's median reprojection error (px) and
    seconds per stage."""

    folder: Path
    frames: int
    found: int
    fps: float
    side: float
    focal: float
    residual_px: float
    audio: bool
    seconds: dict


def face_crops(points, found, *, fps: float, margin: float = 1.9, smooth_seconds: float = 0.3,
               lift: float = 0.12) -> np.ndarray:
    """One square crop per frame, ``(T, 3)``: centre x, centre y, side (pixels of the video), from
    the face-mesh ``points (T, 468, 2)``. The centre is the face box's, ``lift`` × the side above
    it (the forehead and hair belong to the head), smoothed over time by a Gaussian of
    ``smooth_seconds``; the side is ``margin`` × the largest face box of the clip (its 98th
    percentile: a misdetection does not blow it up). Frames without a face take their
    neighbours' (interpolated)."""
    from scipy.ndimage import gaussian_filter1d

    P = np.asarray(points, np.float64)
    ok = np.asarray(found, bool) & np.isfinite(P).all((1, 2))
    if not ok.any():
        raise CaptureError("no face found in any frame: nothing to crop")
    Q = np.where(ok[:, None, None], P[:, list(FACE_OVAL)], 0.0)
    lo, hi = Q.min(1), Q.max(1)
    c = (lo + hi) / 2
    size = (hi - lo).max(1)
    t = np.arange(len(P))
    for k in range(2):
        c[~ok, k] = np.interp(t[~ok], t[ok], c[ok, k])
    side = margin * float(np.percentile(size[ok], 98))
    c[:, 1] -= lift * side
    if smooth_seconds > 0 and len(P) > 1:
        c = gaussian_filter1d(c, smooth_seconds * fps, axis=0, mode="nearest")
    return np.column_stack([c, np.full(len(P), side)])


def crop_frames(frames, boxes, res: int) -> np.ndarray:
    """The crops ``(T, res, res, 3)`` uint8 of ``frames`` (any iterable: a video streams through)
    at ``boxes (T, 3)`` (:func:`face_crops`), by an area-averaging resampling (OpenCV); outside the
    picture is black."""
    import cv2

    out = np.zeros((len(boxes), res, res, 3), np.uint8)
    for k, (f, (cx, cy, side)) in enumerate(zip(frames, boxes)):
        s = res / side
        M = np.array([[s, 0, res / 2 - s * cx], [0, s, res / 2 - s * cy]])
        interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
        if s < 1:  # INTER_AREA works for resize, not for warps: shrink first, then place
            small = cv2.resize(np.asarray(f), None, fx=s, fy=s, interpolation=interp)
            M = np.array([[1.0, 0, res / 2 - s * cx], [0, 1.0, res / 2 - s * cy]])
            out[k] = cv2.warpAffine(small, M, (res, res), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))
        else:
            out[k] = cv2.warpAffine(np.asarray(f), M, (res, res), flags=interp, borderValue=(0, 0, 0))
    return out


def _to_crop(points, boxes, res: int) -> np.ndarray:
    cx, cy, side = (boxes[:, k][:, None] for k in range(3))
    s = res / side
    return np.stack([(points[..., 0] - cx) * s + res / 2, (points[..., 1] - cy) * s + res / 2], -1)


def head_colours(V_frames, F, frames, masks, camera, *, max_views: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex colours of a tracked head from the frames: for up to ``max_views`` frames (evenly
    spread), the vertices the camera sees (a z-buffer) inside the person's mask take the frame's
    colour there, weighted by how squarely they face the camera (cos² of the angle); returns
    ``(colours (n, 3) in [0, 1], seen (n,) bool)``. ``V_frames``: a callable ``frame → (n, 3)``
    posed vertices in camera coordinates."""
    from geoface.mesh.core import vertex_normals
    from geoface.mesh.raster import rasterize_mesh

    T = len(frames)
    pick = np.unique(np.linspace(0, T - 1, min(T, max_views)).round().astype(int))
    n = len(V_frames(0))
    acc = np.zeros((n, 3))
    wsum = np.zeros(n)
    H, W = frames.shape[1:3]
    for k in pick:
        V = V_frames(int(k))
        face, _, depth = rasterize_mesh(V, F, camera)
        uv = np.stack([camera.fx * V[:, 0] / V[:, 2] + camera.cx, camera.fy * V[:, 1] / V[:, 2] + camera.cy], 1)
        px = np.floor(uv).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H) & (V[:, 2] > 0)
        i, j = np.clip(px[:, 1], 0, H - 1), np.clip(px[:, 0], 0, W - 1)
        vis = inside & np.isfinite(depth[i, j]) & (V[:, 2] <= depth[i, j] + 2e-3)  # not behind the z-buffer
        vis &= masks[k][i, j] > 0.5
        N = vertex_normals(V, F)
        view = -V / np.linalg.norm(V, axis=1, keepdims=True)
        cos = np.clip((N * view).sum(1), 0, 1)
        w = np.where(vis, cos ** 2, 0.0)
        acc += w[:, None] * frames[k][i, j]
        wsum += w
    seen = wsum > 1e-3
    col = np.zeros((n, 3))
    col[seen] = acc[seen] / wsum[seen, None]
    return col, seen


def overlay_frames(frames, draw, *, alpha: float = 0.55, colour=(0.45, 0.75, 1.0)):
    """Each frame beside itself with the tracked head drawn over it (``colour``, lit from the
    camera, ``alpha`` opaque): ``draw(k) → (shade (H, W, 3), coverage (H, W))``."""
    c = np.asarray(colour, np.float32)
    for k, f in enumerate(frames):
        img = np.asarray(f, np.float32)
        img = img / 255.0 if img.max() > 1.5 else img
        shade, cov = draw(k)
        a = alpha * np.asarray(cov, np.float32)[..., None]
        over = img * (1 - a) + shade * c * a
        yield np.clip(np.concatenate([img, over], 1), 0, 1)


def capture_head(folder):
    """The tracked head of a capture that :func:`capture_clip` wrote, read back from its files:
    ``(F, posed)`` with ``posed(k) → (n, 3)`` the head of frame ``k`` in world coordinates
    (``camera.json``'s), from ``meta.json``'s ICT identity, ``expressions.npz`` and
    ``head_poses.npz``; the ICT head's own triangles ``F``."""
    from geoface.capture import Capture
    from geoface.synth.ict import load_ict_model
    from geoface.track.head_track import CM_TO_M, neutral_head

    cap = Capture(folder)
    meta = cap.meta(need=True)
    try:
        ident = np.asarray(meta["ict_identity"], np.float64)
        parts = tuple(meta["ict_parts"])
    except (KeyError, TypeError, ValueError) as e:
        raise CaptureError(f"{cap.path}/meta.json: no tracked ICT head ({type(e).__name__}: {e}); "
                           "`geoface capture` writes one") from None
    ex = cap.expressions()
    poses = cap.head_poses()
    if ex is None or poses is None:
        raise CaptureError(f"{cap.path}: needs expressions.npz and head_poses.npz (the head track)")
    model = load_ict_model()
    view = model.view(parts)
    W, names = ex
    order = [names.index(n) for n in model.expression_names]
    neutral = neutral_head(ident, view)
    R, t, piv = poses

    def posed(k: int) -> np.ndarray:
        X = neutral + np.tensordot(W[k, order], view.expression_modes, axes=1) * CM_TO_M
        return (X - piv) @ R[k].T + piv + t[k]

    return view.F, view.labels, posed


def write_overlay(folder, path, *, quiet: bool | None = None) -> Path:
    """``path`` (MP4): the capture's frames, each beside itself with its tracked head drawn over
    it, drawn from the capture's files alone (:func:`capture_head`), with the capture's sound."""
    from geoface.capture import Capture
    from geoface.images import read_image
    from geoface.nn.mesh_render import render_mesh
    from geoface.progress import progress
    from geoface.video import write_video

    cap = Capture(folder)
    cam = cap.camera()
    F, labels, posed = capture_head(folder)
    Fs = F[np.isin(labels[F], (0, 1, 2)).all(1)]  # the skin: eyes and mouth show through
    n = int(F.max()) + 1
    white = np.ones((n, 3))

    def draw(k):
        r = render_mesh(posed(k), Fs, cam, white, shading="headlight")
        return r.rgb, r.alpha

    frames = (np.asarray(read_image(p, "rgb"), np.float32) for p in cap.frame_paths)
    return write_video(progress(overlay_frames(frames, draw), "drawing the overlay", total=len(cap), quiet=quiet,
                                unit="frames"), path, fps=float(cap.meta().get("fps", 25.0)), audio=cap.audio())


def extract_audio(video: Path, wav: Path) -> bool:
    """The video's sound as 16 kHz mono WAV; False when it has none."""
    import subprocess

    from geoface.video import ffmpeg_exe, probe_video

    if not probe_video(video).get("audio"):
        return False
    r = subprocess.run([ffmpeg_exe(), "-nostdin", "-v", "error", "-y", "-i", str(video), "-vn", "-ac", "1", "-ar", "16000",
                        "-c:a", "pcm_s16le", str(wav)], capture_output=True)
    if r.returncode != 0:
        raise CaptureError(f"{video}: its sound could not be decoded ({r.stderr.decode(errors='replace').strip()[-200:]})")
    return True


def capture_clip(source, out_dir, *, res: int = 512, focal: float | None = None, fps: float | None = None,
                 audio=None, head_vertices: int = 6000, overlay: bool = True, margin: float = 1.9,
                 refine: bool = False, settings=None, identity=None, headset: bool = False, overwrite: bool = False,
                 quiet: bool | None = None) -> ClipCapture:
    """Make the capture folder ``out_dir`` of the clip ``source`` (a video file or a folder of
    frames); module doc. ``res``: the crops' side in pixels; ``focal``: the camera's focal length
    in the video's pixels when known (else fitted); ``fps``: a folder's frame rate (default 25);
    ``audio``: a WAV to use as the clip's sound (a silent clip, or better sound);
    ``head_vertices``: the head mesh's size (one Gaussian per vertex for HFM-GS); ``refine``: refine
    the track against the pixels (:func:`geoface.track.head_refine.refine_photometric`; slower).
    ``identity``: the person's ICT identity weights when known (a registration capture's
    ``meta.json`` ``ict_identity``): the head is then held as it is and only expressions, poses
    and the focal length are fitted, in the same head frame as that capture's. ``headset``: the
    clip shows the person wearing a headset (:func:`geoface.track.headset_masks` finds it in each
    crop by the colour where the face mesh's eyes fall): the head is fitted to the face-mesh
    points below it and refined against the pixels below it alone
    (:func:`geoface.track.head_track.below_headset`), what MediaPipe guesses under the visor left
    out; the masks are kept in ``hmd_masks/``."""
    import shutil
    import time

    from geoface._io import check_input, check_outputs, output_folder
    from geoface.capture import (write_camera, write_dense, write_expressions, write_head_poses, write_landmarks,
                                 write_meta)
    from geoface.camera import Camera
    from geoface.images import save_image
    from geoface.mesh.io import save_mesh
    from geoface.progress import progress
    from geoface.synth.ict import load_ict_model, neck_pivot, upper_split
    from geoface.track import (TRACKER, FrameSource, face_confidence, facemesh_points, ibug68_from_mediapipe,
                               person_masks)
    from geoface.track.head_track import ICT_TRACK_PARTS, fit_head_track

    src, out = Path(source), Path(out_dir)
    if not (16 <= int(res) <= 4096):
        raise CaptureError(f"res must be in 16..4096; got {res}")
    if focal is not None and not (np.isfinite(focal) and focal > 0):
        raise CaptureError(f"focal must be a positive number of pixels; got {focal!r}")
    if fps is not None and not (np.isfinite(fps) and 0 < fps <= 1000):
        raise CaptureError(f"fps must be in (0, 1000]; got {fps!r}")
    if not (1.0 <= margin <= 6.0):
        raise CaptureError(f"margin must be in 1..6 face sizes; got {margin}")
    if head_vertices < 200:
        raise CaptureError(f"head_vertices must be at least 200; got {head_vertices}")
    ins = [src] + ([Path(audio)] if audio is not None else [])
    for p in ins:
        check_input(p)
    if audio is not None and Path(audio).suffix.lower() != ".wav":
        raise CaptureError(f"{audio}: the sound must be a WAV file")
    check_outputs(ins, [out], force=overwrite)
    secs = {}
    t0 = time.perf_counter()
    source = FrameSource(src)  # decoded afresh for each pass: a long clip never sits in memory whole
    names = source.names
    if len(source) < 2:
        raise CaptureError(f"{src}: a capture needs a clip (2 frames or more); got {len(source)}")
    rate = float(fps or source.fps or 25.0)
    W0, H0 = source.size
    secs["decode"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dense = facemesh_points(source, video=True, total=len(source), quiet=quiet)
    found = np.isfinite(dense).all((1, 2))
    if not found.any():
        raise CaptureError(f"{src}: no face found in any of the {len(dense)} frames")
    names = names[:len(dense)]  # a container that claimed more frames than it holds
    boxes = face_crops(dense, found, fps=rate, margin=margin)
    crops = crop_frames(progress(source, "cropping", total=len(source), quiet=quiet, unit="frames"), boxes, int(res))
    pts = _to_crop(dense, boxes, int(res))
    secs["landmarks"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    masks = person_masks(crops, quiet=quiet)
    conf = face_confidence(crops, quiet=quiet)
    secs["masks"] = time.perf_counter() - t0
    side = float(boxes[0, 2])
    scale = res / side
    held = None if identity is None else np.asarray(identity, np.float64).reshape(-1)
    use, region, hmd, seen, fit_pts = None, None, None, masks, pts
    if headset:  # the face below the visor only: MediaPipe's points under it are guesses
        from scipy.ndimage import binary_dilation

        from geoface.track import headset_masks
        from geoface.track.head_track import below_headset

        hmd = headset_masks(crops, points=np.where(found[:, None, None], pts, np.nan))
        use, region = below_headset(held if held is not None else np.zeros(0))
        # the person less the headset and a rim of 3 pixels (its edge, blurred, is neither)
        seen = masks * ~np.stack([binary_dilation(h, iterations=3) for h in hmd])
        fit_pts = np.where(use[None, :, None], pts, np.nan)
    track = fit_head_track(pts, (int(res), int(res)), found=found, focal=None if focal is None else focal * scale,
                           focal_init=1.2 * max(W0, H0) * scale, settings=settings, use=use, identity=held,
                           quiet=quiet)
    secs["head_track"] = track.seconds
    photo = None
    rgb = crops.astype(np.float32) / 255.0
    if refine:
        from geoface.track.head_refine import refine_photometric

        track, ref = refine_photometric(track, rgb, seen.astype(np.float32), fit_pts, identity=held is None,
                                        region=region, quiet=quiet)
        secs["refine"] = ref.seconds
        photo = [round(float(np.nanmean(ref.before)), 4), round(float(np.nanmean(ref.after)), 4)]
    t0 = time.perf_counter()
    model = load_ict_model()
    view = model.view(ICT_TRACK_PARTS)
    neutral = track.neutral()
    pivot = neck_pivot(neutral, view.landmarks, view.labels)
    R0, t0v = track.R[0], track.t[0]
    A = np.einsum("ji,tjk->tik", R0, track.R)  # R0ᵀ R_t: each frame's head in the world of frame 0
    b = np.einsum("ji,tj->ti", R0, track.t - t0v)
    tp = b + A @ pivot - pivot  # about the neck: X' = A (X − p) + p + t
    cam_crop = track.camera()
    cam = Camera(cam_crop.fx, cam_crop.fy, cam_crop.cx, cam_crop.cy, int(res), int(res), R0, t0v)
    idx, w = ibug68_from_mediapipe()
    lm68 = np.einsum("tkjd,kj->tkd", np.nan_to_num(pts)[:, idx], w)
    if not found.all():  # frames without a face: the landmarks the track projects there
        proj = track.points()
        lm68[~found] = np.einsum("tkjd,kj->tkd", proj[~found][:, idx], w)
    # the head's colours from the frames, then decimated for the avatars

    def posed(k):
        return track.posed(k)

    col, coloured = head_colours(posed, view.F, rgb, seen, cam_crop)  # (not from a headset's pixels)
    if coloured.any():
        from scipy.spatial import cKDTree

        _, nn = cKDTree(neutral[coloured]).query(neutral[~coloured])
        col[~coloured] = col[coloured][nn]
    from geoface.repair.remesh import remesh

    if head_vertices < len(neutral):
        r = remesh(neutral, view.F, int(head_vertices), method="decimate")
        Vd, Fd = np.asarray(r.V), np.asarray(r.F)
        from scipy.spatial import cKDTree

        _, nn = cKDTree(neutral).query(Vd)
        Cd = col[nn]
    else:
        Vd, Fd, Cd = neutral, view.F, col
    secs["head_mesh"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with output_folder(out, overwrite) as tmp:
        (tmp / "frames").mkdir()
        (tmp / "masks").mkdir()
        for k in progress(range(len(crops)), "writing frames", quiet=quiet, unit="frames"):
            name = f"{k:06d}.png"
            m = masks[k]
            save_image(tmp / "frames" / name, rgb[k] * m[..., None], atomic=False)
            save_image(tmp / "masks" / name, np.round(m * 255).astype(np.uint8), atomic=False)
            if hmd is not None:
                (tmp / "hmd_masks").mkdir(exist_ok=True)
                save_image(tmp / "hmd_masks" / name, hmd[k].astype(np.uint8) * 255, atomic=False)
        write_landmarks(tmp, lm68, found=found, confidence=conf, tracker=TRACKER, dense="landmarks_dense.npz")
        write_dense(tmp, pts, found, conf)
        write_camera(tmp, cam)
        write_head_poses(tmp, A, tp, pivot)
        write_expressions(tmp, track.expressions, track.expression_names)
        save_mesh(tmp / "head.ply", V=Vd, F=Fd, colors=np.clip(Cd, 0, 1))
        has_audio = False
        if audio is not None:
            shutil.copyfile(audio, tmp / "audio.wav")
            has_audio = True
        elif src.is_file():
            has_audio = extract_audio(src, tmp / "audio.wav")
        write_meta(tmp, {
            "fps": rate, "source": "video", "input": src.name, "input_size": [int(W0), int(H0)], "frames": names,
            "crop_boxes": np.round(boxes, 2).tolist(), "res": int(res),
            "y_split": upper_split(neutral, view.landmarks), "up": [0, 1, 0],
            "ict_identity": [round(float(x), 6) for x in track.identity], "ict_parts": list(ICT_TRACK_PARTS),
            "focal_px": track.focal, "focal_given": focal is not None, "found": int(found.sum()),
            "refined": bool(refine), "photometric_error_before_after": photo,
            "identity_held": held is not None, "headset": bool(headset),
            "residual_px": [None if not np.isfinite(x) else round(float(x), 3) for x in track.residual_px],
            "tracker": {"landmarks": TRACKER, "head": "ICT-FaceKit fit to MediaPipe's 468 points (geoface.track.head_track)"},
            "seconds": {k: round(v, 2) for k, v in secs.items()}})
        if overlay:
            write_overlay(tmp, tmp / "overlay.mp4", quiet=quiet)
    secs["write"] = time.perf_counter() - t0
    return ClipCapture(out, len(crops), int(found.sum()), rate, side, track.focal,
                       float(np.nanmedian(track.residual_px)), has_audio, secs)
