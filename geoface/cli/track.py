"""``geoface track INPUT -o OUT``: 68 face landmarks, confidences and masks from a real face
tracker, for an image, a folder of frames, a video or a capture folder."""
from __future__ import annotations

from .._args import number

from pathlib import Path

from ..errors import GeofaceError


def cmd_track(args) -> int:
    from ..track import TRACKER, track_capture, track_input
    from ..progress import args_quiet

    src = Path(args.input)
    if (src / "frames").is_dir():  # a capture folder: a copy of it with the tracker's landmarks and masks
        if args.masks or args.fps:
            raise GeofaceError("--masks and --fps are for images and videos; a capture folder gets masks/ in OUT_DIR "
                               "(--no-masks keeps its own)")
        tr = track_capture(src, args.output, masks=not args.no_masks, overwrite=args.force, quiet=args_quiet(args))
        what = "" if args.no_masks else "; masks from selfie segmentation"
    else:
        if args.no_masks:
            raise GeofaceError("--no-masks is for capture folders; an image or video gets masks only with --masks DIR")
        tr = track_input(src, args.output, masks_dir=args.masks, smooth=args.smooth, fps=args.fps,
                         overwrite=args.force, quiet=args_quiet(args))
        what = (f"; confidence {tr.confidence.min():.2f}-{tr.confidence.max():.2f}"
                + ("; smoothed (One Euro)" if tr.smoothed else "") + (f"; masks in {args.masks}" if args.masks else ""))
    n = len(tr.found)
    missing = n - int(tr.found.sum())
    print(f"{src} -> {Path(args.output)}: {TRACKER} landmarks on {n - missing} of {n} frames"
          + (f" ({missing} interpolated)" if missing else "") + what)
    return 0


def register(sub, common) -> None:
    """``geoface track``."""
    s = sub.add_parser("track", help="68 face landmarks (and masks) from the pixels of an image, a folder of frames, "
                                     "a video or a capture folder, with MediaPipe (needs geoface[track])")
    s.add_argument("input", metavar="INPUT",
                   help="an image, a folder of images (a video's frames, sorted by name), a video (.mp4, .mov, ...), "
                        "or a capture folder (frames/*.png, camera.json, ...)")
    s.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="landmarks.json for an image, folder or video (the format capture folders read: names, "
                        "points [T, 68, 2] px, found, confidence); for a capture folder, OUT_DIR: the same capture "
                        "with the tracker's landmarks and masks (the originals are not copied)")
    s.add_argument("--masks", default=None, metavar="DIR",
                   help="images and videos: also the person's masks (selfie segmentation), one PNG per frame in DIR")
    s.add_argument("--smooth", action="store_true",
                   help="videos and folders: also smooth the landmarks with a One Euro filter (no lag on fast motion; "
                        "MediaPipe's video mode already filters them, so the gain is small)")
    s.add_argument("--fps", type=number(float, 0, 1000, lo_open=True), default=None, metavar="FPS",
                   help="frame rate of a folder of frames, for the smoothing (default: the video's, else 25)")
    s.add_argument("--no-masks", action="store_true", help="capture folders: keep the capture's own masks/ "
                                                           "(default: segment the person)")
    s.set_defaults(func=cmd_track)
