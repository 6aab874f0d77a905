"""``geoface capture VIDEO|FRAMES -o DIR``: a real clip becomes a capture folder (frames, masks,
landmarks, camera, the ICT head tracked through the clip, sound, an overlay video to watch)."""
from __future__ import annotations

from pathlib import Path

from .._args import number


def cmd_capture(args) -> int:
    from ..avatar.clip import capture_clip
    from ..progress import args_quiet

    r = capture_clip(args.input, args.output, res=args.res, focal=args.focal, fps=args.fps, audio=args.audio,
                     head_vertices=args.head_vertices, overlay=not args.no_overlay, margin=args.margin, refine=args.refine,
                     overwrite=args.force, quiet=args_quiet(args))
    missing = r.frames - r.found
    sound = "sound in audio.wav" if r.audio else "no sound (give one with --audio WAV for `talk train`)"
    print(f"{Path(args.input)} -> {r.folder}: {r.frames} frames at {r.fps:g} fps, {args.res}² crops of "
          f"{r.side:.0f} px; a face on {r.found}" + (f" ({missing} from the track)" if missing else "")
          + f"; ICT head tracked at {r.frames / max(r.seconds['head_track'], 1e-9):.1f} frames/s"
          + (f" and refined at {r.frames / max(r.seconds['refine'], 1e-9):.1f}" if 'refine' in r.seconds else "") + ", "
          f"median reprojection {r.residual_px:.2f} px, focal {r.focal:.0f} px; {sound}"
          + ("" if args.no_overlay else f"; watch {r.folder / 'overlay.mp4'}"))
    return 0


def register(sub, common) -> None:
    """``geoface capture``."""
    s = sub.add_parser("capture",
                       help="a video of a person (or its frames) -> a capture folder for the avatars: frames, masks, "
                            "landmarks, camera, the ICT-FaceKit head tracked through the clip, sound, an overlay video "
                            "(needs geoface[track])")
    s.add_argument("input", metavar="VIDEO|FRAMES",
                   help="a video (.mp4, .mov, ...) or a folder of frames (images sorted by name) of one person")
    s.add_argument("-o", "--output", required=True, metavar="DIR", help="the capture folder to write (must not exist "
                                                                         "unless --force)")
    s.add_argument("--res", type=number(int, 16, 4096), default=512, metavar="N",
                   help="side of the square crops that follow the face, in pixels (default: 512, as the papers)")
    s.add_argument("--focal", type=number(float, 0, lo_open=True), default=None, metavar="PX",
                   help="the camera's focal length in the video's pixels, when known (default: fitted with the head, "
                        "starting from 1.2 x the larger side)")
    s.add_argument("--fps", type=number(float, 0, 1000, lo_open=True), default=None, metavar="FPS",
                   help="frame rate of a folder of frames (default: the video's, else 25)")
    s.add_argument("--audio", default=None, metavar="WAV",
                   help="a WAV to use as the clip's sound (default: the video's own, when it has one)")
    s.add_argument("--head-vertices", type=number(int, 200, 100_000), default=6000, metavar="N",
                   help="vertices of head.ply, the person's head (HFM-GS starts one Gaussian on each; default: 6000)")
    s.add_argument("--margin", type=number(float, 1, 6), default=1.9, metavar="X",
                   help="the crop's side in face sizes (default: 1.9: the head and a little of the shoulders)")
    s.add_argument("--refine", action="store_true",
                   help="refine the head track against the pixels (the face's lit colours matched frame by frame "
                        "and its shape refined; about 0.4 frames/s at 512 on 2 cores; docs/video.md has what it gains)")
    s.add_argument("--no-overlay", action="store_true", help="do not draw overlay.mp4 (the tracked head over the frames)")
    s.set_defaults(func=cmd_capture)
