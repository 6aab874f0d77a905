"""``geoface talk export`` and ``geoface hmd export``: an avatar's frames as 3DGS PLY files
(:mod:`geoface.drive.avatars`)."""
from __future__ import annotations

from pathlib import Path

from geoface._args import number
from geoface.errors import GeofaceError


def cmd_avatar_export(args) -> int:
    """``talk export`` / ``hmd export``: frames of an avatar as standard 3DGS PLY files."""
    from geoface.drive.avatars import avatar_drive, export_frames, parse_frames

    out = Path(args.output)
    if out.suffix.lower() != ".ply" and out.exists() and any(out.iterdir()) and not args.force:
        raise GeofaceError(f"{out} is not empty; use --force to overwrite")
    drive = avatar_drive(args.model_dir, args.drive, fps=getattr(args, "fps", 25.0))
    frames = parse_frames(args.frames if args.frames is not None else ("0" if out.suffix.lower() == ".ply" else "all"),
                          drive.n_frames)
    if out.suffix.lower() == ".ply":
        paths = export_frames(drive, out, frames)
    else:
        from geoface._io import output_folder

        with output_folder(out, args.force) as tmp:  # every PLY at once, or none
            paths = [out / Path(p).relative_to(tmp) for p in export_frames(drive, tmp, frames)]
    n = len(drive.gaussians(frames[0]).means)
    where = str(paths[0]) if len(paths) == 1 else f"{out}/frame_*.ply ({len(paths)} files)"
    print(f"{args.model_dir} driven by {drive.what} -> {where}: {n:,} Gaussians per frame (3DGS PLY)")
    return 0


def add_export_parser(hs, common, what: str, drive_help: str, required: bool) -> None:
    x = hs.add_parser("export", parents=[common], help=f"{what} frames as standard 3DGS PLY files (other viewers open them)")
    x.add_argument("model_dir", metavar="MODEL_DIR", help='a trained avatar model folder')
    x.add_argument("--drive", required=required, default=None, help=drive_help)
    x.add_argument("--frames", default=None, metavar="T|A:B[:S]|all",
                   help="which frames (default: frame 0 into a .ply, every frame into a folder)")
    x.add_argument("--fps", type=number(float, 0.1, 240), default=25.0, help="frame rate of a WAV drive (25)")
    x.add_argument("-o", "--output", required=True, metavar="OUT.ply|OUT_DIR",
                   help='a .ply for one frame, a folder for several')
    x.set_defaults(func=cmd_avatar_export)
