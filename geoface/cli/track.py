"""``geoface track CAPTURE -o OUT``: a capture's landmarks and masks from a real face tracker."""
from __future__ import annotations

from pathlib import Path


def cmd_track(args) -> int:
    from ..track import TRACKER, track_capture
    from ..progress import args_quiet

    tr = track_capture(args.capture, args.output, masks=not args.no_masks, overwrite=args.force,
                       quiet=args_quiet(args))
    n = len(tr.found)
    missing = n - int(tr.found.sum())
    print(f"{args.capture} -> {Path(args.output)}: {TRACKER} landmarks on {n - missing} of {n} frames"
          + (f" ({missing} interpolated)" if missing else "") + ("" if args.no_masks else "; masks from selfie segmentation"))
    return 0


def register(sub, common) -> None:
    """``geoface track``."""
    s = sub.add_parser("track", help="track a capture folder's face with MediaPipe: landmarks.json and masks/ "
                                     "from the frames alone (needs geoface[track])")
    s.add_argument("capture", metavar="CAPTURE", help="a capture folder (frames/*.png, camera.json, ...)")
    s.add_argument("-o", "--output", required=True, metavar="OUT_DIR",
                   help="the same capture with the tracker's landmarks and masks (the originals are not copied)")
    s.add_argument("--no-masks", action="store_true", help="keep the capture's own masks/ (default: segment the person)")
    s.set_defaults(func=cmd_track)
