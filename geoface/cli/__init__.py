"""The ``geoface`` command: thin subcommands that parse, call one library function, report.

Bad input never produces a traceback: every :class:`~geoface.GeofaceError` (and file
system error) becomes one line on stderr and exit code 2.  Outputs are written
atomically, and an input file is never overwritten.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from .. import __version__
from ..errors import GeofaceError, GeofaceWarning
from .._args import SEED, add_json, number, output_option, resolve_output

from ._common import Parser, guard_by_table, axis, one_line
from .dataset import dataset_options, cmd_dataset_build, cmd_dataset_ict
from .geometry import cmd_convert, cmd_inspect, cmd_param, cmd_reconstruct, cmd_repair, cmd_view
from .synth import SURFACES, cmd_synth_head, cmd_synth_ict, cmd_synth_pack_ict, cmd_synth_surface

__all__ = ["main", "build_parser"]

def _verbs(parser, common):
    """Second-level subcommands (``geoface synth head``); each accepts the common flags (-q)."""
    sp = parser.add_subparsers(dest="what", metavar="WHAT", parser_class=Parser)
    sp.required = True
    add = sp.add_parser
    sp.add_parser = lambda *a, **k: add(*a, parents=[common], **k)
    return sp


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="geoface", description="Geometry processing of head and face meshes.")
    p.add_argument("--version", action="version", version=f"geoface {__version__}")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.add_argument("-v", "--verbose", action="store_true", help="also the solvers' iterations")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress output")
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="also the solvers' iterations (Ricci flow, optimal transport, training)")
    common.add_argument("--force", action="store_true", default=argparse.SUPPRESS,
                        help="replace outputs that exist (never an input)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    _add = sub.add_parser
    sub.add_parser = lambda *a, **k: _add(*a, parents=[common], **k)  # every verb accepts -q

    s = sub.add_parser("inspect", help="print a mesh's topology report")
    s.add_argument("file")
    add_json(s, "the report")
    s.set_defaults(func=cmd_inspect)

    s = sub.add_parser("repair", help="turn any mesh into a topological disk")
    s.add_argument("input")
    s.add_argument("-o", "--output", required=True, help="output mesh (obj, ply, off, stl, glb)")
    s.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto",
                   help="how to open a closed surface (default auto: plane cut near the bottom if closed)")
    s.add_argument("--up", default="auto", type=axis(), help="up axis: auto (default: from the shape, any axis convention: a human head "
                   "by the head template, else the opening, a flat cut, the plane it stands on) or x, y, z, -x, -y, -z")
    s.add_argument("--height", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.02, help="plane cut height as a fraction of the extent along up (0.02)")
    s.add_argument("--cap-area", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.02, help="area fraction removed by --open cap (0.02)")
    s.add_argument("--target-vertices", type=number(int, 16, 10_000_000), default=None, help="remesh to about this many vertices")
    s.add_argument("--min-component-area", type=number(float, 0, 1, hi_open=True), default=None, help="drop components below this area fraction")
    add_json(s, "the report and the changes")
    s.set_defaults(func=cmd_repair)

    s = sub.add_parser("param", help="parameterize a disk onto the unit square (writes UVs)")
    s.add_argument("input")
    s.add_argument("-o", "--output", required=True, help="output mesh with UVs (obj, ply, glb)")
    s.add_argument("--method", choices=["ricci", "harmonic", "lscm"], default="ricci",
                   help="ricci: conformal map to a rectangle (default); harmonic: to the square by arc length; lscm: free boundary")
    s.add_argument("--corners", default=None, help="four boundary vertex indices I,J,K,L in boundary order")
    s.add_argument("--corner-set", type=number(int, 0, 7), default=None, help="one of the 8 augmentation corner sets (0..7)")
    s.add_argument("--fit", choices=["rectangle", "uniform", "stretch"], default="rectangle",
                   help="ricci: write the conformal rectangle itself, height 1 (default), fit it into the unit square "
                        "keeping its aspect (uniform), or stretch it to the square (no longer conformal)")
    s.add_argument("--tolerance", type=number(float, 0, 1, lo_open=True), default=1e-9, help="curvature tolerance of the flow (radians)")
    s.add_argument("--repair", action="store_true", help="run make_disk first")
    s.add_argument("--up", default="auto", type=axis(), help="up axis for --repair (default auto: from the shape)")
    add_json(s, "the metrics")
    s.set_defaults(func=cmd_param)

    s = sub.add_parser("convert", help="mesh -> geometry images (+ reconstruction, preview, metrics)")
    s.add_argument("input")
    output_option(s, "OUT_DIR", "folder for the geometry images, preview and metrics")
    s.add_argument("--res", type=number(int, 4, 8192), default=512, help="image resolution N (default 512)")
    s.add_argument("--roi", default="face", help="region magnified by --lam: face (a frontal cone), none, or a mask file (.npy, .txt, .json)")
    s.add_argument("--lam", type=number(float, 0, 1000, lo_open=True), default=2.5, help="mass factor on the ROI (paper: 2.5; 1 = area-preserving)")
    s.add_argument("--augment", type=number(int, 1, 8), default=1, help="number of corner sets, 1..8 (one image set each)")
    s.add_argument("--corner-set", type=number(int, 0, 7), default=None, metavar="K",
                   help="convert with corner set K (0..7) only, written directly in OUT_DIR (0: the default, face "
                        "upright and centred; 4: the boundary point under the chin at a corner)")
    s.add_argument("--method", choices=["ot", "conformal"], default="ot", help="measure-preserving (ot, default) or conformal")
    s.add_argument("--ot-tol", type=number(float, 0, 1, lo_open=True, hi_open=True), default=1e-3, help="OT tolerance: max relative cell-area error (1e-3)")
    s.add_argument("--smooth", type=number(int, 0, 1000), default=0, help="Laplacian smoothing iterations of the reconstruction")
    s.add_argument("--no-reconstruct", dest="reconstruct", action="store_false",
                   help="skip reconstruction.obj and its error report (the images come first either way; "
                        "dataset builds skip them unless --reconstruct)")
    s.add_argument("--up", default="auto", type=axis(), help="up axis: where closed heads are cut open, and which way the face is upright "
                   "in the image; auto (default): from the shape, in any axis convention (a human head by the head template, "
                   "else the opening, a flat cut, the plane it stands on; uncertain cases say so), or x, y, z, -x, -y, -z")
    s.add_argument("--front", default="auto", type=axis(), help="face direction: auto (default: towards the centroid of a --roi mask "
                   "file; without one, the front found with --up auto, or where the mesh faces about a given --up: symmetry "
                   "and detail, as `view` finds it) or an axis (z, -x, ...)")
    s.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto", help="how to open a closed surface")
    s.set_defaults(func=cmd_convert)

    s = sub.add_parser("reconstruct", help="geometry-image folder -> textured mesh")
    s.add_argument("dir")
    s.add_argument("-o", "--output", required=True, help="output mesh (obj writes .mtl, texture and normal map too)")
    s.add_argument("--smooth", type=number(int, 0, 1000), default=0, help="Laplacian smoothing iterations")
    s.set_defaults(func=cmd_reconstruct)

    s = sub.add_parser("view", help="look at meshes, geometry images, splats, avatars: a window, a PNG, a video or a web page")
    s.add_argument("file", nargs="+", metavar="PATH",
                   help="a mesh, a geometry-image folder; with --web also a 3DGS .ply or an avatar model folder "
                        "(several: side by side)")
    s.add_argument("--screenshot", default=None, metavar="OUT.png", help="render off-screen to this PNG and exit")
    s.add_argument("--turntable", default=None, metavar="OUT.mp4",
                   help="render a turn around the mesh (the surface of a geometry image, or a 3DGS .ply) to an MP4 and exit")
    s.add_argument("--seconds", type=number(float, 0.5, 120), default=6.0, help="length of --turntable (6 s, 25 fps)")
    s.add_argument("--view", default="front",
                   choices=["front", "back", "left", "right", "top", "bottom", "iso", "xy", "xz", "yz"],
                   help="camera: front (default; found from the mesh, whichever axis it was scanned along), back, "
                        "left, right, top, bottom, iso; or a fixed axis view xy (looking down -z), xz, yz")
    s.add_argument("--up", default=None, type=axis(auto=False), metavar="AXIS",
                   help="the data's up direction: +y (default), -y, +z, ... or three numbers")
    s.add_argument("--meta", default=None, metavar="JSON",
                   help="a `geoface synth --meta` file: its face mask tells the front (default: MESH.json if present)")
    s.add_argument("--uv-distortion", action="store_true", help="show the UV layout coloured by distortion (mesh with UVs)")
    s.add_argument("--metric", choices=["qc", "area"], default="qc", help="distortion measure for --uv-distortion (qc)")
    s.add_argument("--size", default="1024,768", metavar="W,H",
                   help="window / picture size in pixels (1024,768); for a geometry-image montage H is the tile size")
    w = s.add_argument_group("web viewer (--web)")
    w.add_argument("--web", action="store_true", help="serve an interactive 3D page (viser) and print its URL")
    w.add_argument("--html", default=None, metavar="OUT.html",
                   help="write the 3D page as one self-contained file that opens from disk (no server) and exit")
    w.add_argument("--host", default="127.0.0.1", help="address to listen on (127.0.0.1: this machine only; 0.0.0.0: all)")
    w.add_argument("--port", type=number(int, 0, 65535), default=8080, help="port (8080)")
    w.add_argument("--drive", default=None, metavar="WAV|DIR",
                   help="what drives an avatar: a WAV or a `talk synth` folder (talk models), a usage folder (hmd models)")
    w.add_argument("--fps", type=number(float, 1, 120), default=25.0, help="frame rate of a talking avatar driven by a WAV (25)")
    w.add_argument("--exit-after", type=number(float, 0, lo_open=True), default=None, metavar="S",
                   help="stop the server after S seconds")
    w.add_argument("--idle-exit", type=number(float, 0, lo_open=True), default=None, metavar="S",
                   help="stop the server S seconds after the last browser has left")
    s.set_defaults(func=cmd_view)

    s = sub.add_parser("dataset", help="build geometry-image datasets from folders of meshes")
    dv = _verbs(s, common)
    b = dv.add_parser("build", help="every mesh x corner set -> a geometry-image folder (resumable, parallel)")
    b.add_argument("in_dir", help="folder of meshes (optional <stem>.json face masks, labels.jsonl)")
    output_option(b, "OUT_DIR", "the dataset folder (resumed when it exists)")
    b.add_argument("--labels", default=None, help="labels/prompts per mesh stem (.jsonl or .json; default IN_DIR/labels.jsonl)")
    b.add_argument("--roi", choices=["auto", "face", "none"], default="auto", help="auto: <stem>.json face mask when present, else the face cone")
    dataset_options(b)
    b.set_defaults(func=cmd_dataset_build)
    b = dv.add_parser("ict", help="labelled real heads of the ICT-FaceKit model -> geometry images (resumable, parallel)")
    output_option(b, "OUT_DIR", "the dataset folder (resumed when it exists)")
    b.add_argument("--count", type=number(int, 1, 10_000_000), required=True, help="number of heads (one identity each)")
    b.add_argument("--seed", type=SEED, default=0, help="draws identities, expressions, prompts and the split")
    b.add_argument("--model", default=None, help="the ICT-FaceKit model (.npz or a clone; default: the copy shipped with geoface)")
    b.add_argument("--mix-share", type=number(float, 0, 1), default=0.3, help="share of random ARKit mixes (the rest: named presets)")
    b.add_argument("--heldout-share", type=number(float, 0, 1), default=0.2, help="share of identities labelled split=heldout")
    b.add_argument("--roi", choices=["auto", "face", "none"], default="auto", help="auto: the model's face area")
    dataset_options(b)
    b.set_defaults(func=cmd_dataset_ict)

    from ..learn.cli import register as register_ddpm  # argparse only: torch loads inside the commands
    from ..learn.texture_cli import register as register_texture

    register_ddpm(sub, common)

    from ..splat.cli import register as register_splat  # argparse only: torch loads inside the command

    register_splat(sub, common)
    from ..hfm.cli import register as register_hmd

    register_hmd(sub, common)
    from ..thgs.cli import register as register_talk

    register_talk(sub, common)
    register_texture(sub, common)

    s = sub.add_parser("synth", help="write procedural test geometry")
    ss = _verbs(s, common)
    h = ss.add_parser("head", help="the procedural expressive head")
    h.add_argument("-o", "--output", required=True, help="output mesh (obj with texture, ply with colours, ...)")
    h.add_argument("--vertices", type=number(int, 1000, 200_000), default=20000, help="about this many vertices")
    h.add_argument("--seed", type=SEED, default=0, help="draws the identity")
    h.add_argument("--expression", default=None, help="e.g. smile=0.8,jaw_open=0.3")
    h.add_argument("--texture-size", type=number(int, 16, 8192), default=512, help="texture image size in pixels")
    h.add_argument("--meta", default=None, help="also write identity, expression, landmarks and face mask as JSON")
    h.set_defaults(func=cmd_synth_head)
    i = ss.add_parser("ict", help="a real head of the ICT-FaceKit morphable model (identity, expression, parts)")
    i.add_argument("-o", "--output", required=True)
    i.add_argument("--seed", type=SEED, default=0, help="draws the identity weights ~ N(0, 1)")
    i.add_argument("--identity", default=None, metavar="W1,W2,...", help="identity weights instead of --seed (0,0 = the mean head)")
    i.add_argument("--n-identity", type=number(int, 0, 100), default=None, help="with --seed: draw only the first N modes")
    i.add_argument("--expression", default=None, help="ARKit blendshapes, e.g. mouthSmile_L=1,jawOpen=0.3 (weights in [0, 1])")
    i.add_argument("--parts", default="skin", help="skin (default: face, head and neck), face, head, eyes, teeth, mouth, "
                   "eye_extras or all; comma-separated")
    i.add_argument("--model", default=None, help="the model (.npz or an ICT-FaceKit clone; default: the copy shipped with geoface)")
    i.add_argument("--meta", default=None, help="also write weights, landmarks, face mask and regions as JSON (--roi for convert)")
    i.set_defaults(func=cmd_synth_ict)
    k = ss.add_parser("pack-ict", help="pack an ICT-FaceKit clone (FaceXModel/ OBJs) into one .npz")
    k.add_argument("clone", help="the clone (or its FaceXModel folder)")
    k.add_argument("-o", "--output", required=True, metavar="MODEL.npz")
    k.set_defaults(func=cmd_synth_pack_ict)
    a = ss.add_parser("surface", help="an analytic surface")
    a.add_argument("name", choices=SURFACES)
    a.add_argument("-o", "--output", required=True)
    a.add_argument("--resolution", type=number(int, 2, 2048), default=24, help="grid resolution of the surface")
    a.add_argument("--seed", type=SEED, default=0, help="for the random surfaces")
    a.set_defaults(func=cmd_synth_surface)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        with warnings.catch_warnings():
            warnings.simplefilter("always", GeofaceWarning)
            warnings.showwarning = _show_warning
            resolve_output(parser, args)
    except SystemExit as e:  # a usage error (one line already printed), --help or --version
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    if not hasattr(args, "force"):
        args.force = False
    import os

    from .. import progress as _progress

    # the library is quiet unless asked; the command line shows progress unless -q (or
    # GEOFACE_QUIET=1, as the tests set)
    was_quiet, was_verbose = _progress.QUIET, _progress.VERBOSE
    _progress.set_quiet(bool(args.quiet) or os.environ.get("GEOFACE_QUIET", "") not in ("", "0"))
    _progress.set_verbose(bool(getattr(args, "verbose", False)) or was_verbose)
    try:
        return _run(args)
    finally:
        _progress.set_quiet(was_quiet)
        _progress.set_verbose(was_verbose)


def _run(args) -> int:
    import signal

    terminated = []

    def _on_sigterm(signum, frame):  # like SIGINT: unwind, so temporary outputs are removed
        terminated.append(signum)
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not in the main thread (an embedding application)
        pass
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", GeofaceWarning)
            warnings.showwarning = _show_warning
            guard_by_table(args)
            return int(args.func(args) or 0)
    except GeofaceError as exc:
        print(f"geoface: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(one_line(f"geoface: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("geoface: terminated" if terminated else "geoface: interrupted", file=sys.stderr)
        return 143 if terminated else 130


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"geoface: warning: {one_line(message)}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
