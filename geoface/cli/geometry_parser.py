"""The command line of the geometry verbs (inspect, repair, param, convert, reconstruct, view):
their options, defaults and help; the commands are in :mod:`geoface.cli.geometry`."""
from __future__ import annotations

from .geometry import cmd_convert, cmd_inspect, cmd_param, cmd_reconstruct, cmd_repair, cmd_view


def register(sub, common) -> None:
    """The geometry verbs: inspect, repair, param, convert, reconstruct, view."""
    from .._args import add_json, number, output_option
    from ._common import axis

    s = sub.add_parser("inspect", help="print a mesh's topology report, and the face found on it")
    s.add_argument("file", help='a mesh (obj, ply, off, stl, glb, ...)')
    s.add_argument("--no-face", dest="face", action="store_false",
                   help="do not look for the face (renders of the mesh and the face tracker: about a second)")
    add_json(s, "the report")
    s.set_defaults(func=cmd_inspect)

    s = sub.add_parser("repair", help="turn any mesh into a topological disk")
    s.add_argument("input", metavar="MESH", help="a mesh or point cloud (obj, ply, off, stl, glb, ...)")
    s.add_argument("-o", "--output", required=True, help="output mesh (obj, ply, off, stl, glb)")
    s.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto",
                   help="how to open a closed surface (default auto: plane cut near the bottom if closed)")
    s.add_argument("--up", default="auto", type=axis(), help="up axis: auto (default: from the face, found by looking at renders "
                   "of the surface, in any pose; without one from the shape: the head template, the opening, a flat cut, the "
                   "plane it stands on) or x, y, z, -x, -y, -z")
    s.add_argument("--no-find-face", dest="find_face", action="store_false",
                   help="with --up auto, do not look for the face (the shape's cues alone)")
    s.add_argument("--height", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.02, help="plane cut height as a fraction of the extent along up (0.02)")
    s.add_argument("--cap-area", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.02, help="area fraction removed by --open cap (0.02)")
    s.add_argument("--target-vertices", type=number(int, 16, 10_000_000), default=None, help="remesh to about this many vertices")
    s.add_argument("--min-component-area", type=number(float, 0, 1, hi_open=True), default=None, help="drop components below this area fraction")
    add_json(s, "the report and the changes")
    s.set_defaults(func=cmd_repair)

    s = sub.add_parser("param", help="parameterize a disk onto the unit square (writes UVs)")
    s.add_argument("input", metavar="MESH", help="a mesh or point cloud (obj, ply, off, stl, glb, ...)")
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
    s.add_argument("input", metavar="MESH", help="a mesh or point cloud (obj, ply, off, stl, glb, ...)")
    output_option(s, "OUT_DIR", "folder for the geometry images, preview and metrics")
    s.add_argument("--res", type=number(int, 4, 8192), default=512, help="image resolution N (default 512)")
    s.add_argument("--roi", default="face", help="region magnified by --lam: face (a frontal cone), none, or a mask file (.npy, .txt, .json)")
    s.add_argument("--lam", type=number(float, 0, 1000, lo_open=True), default=2.5, help="mass factor on the ROI (paper: 2.5; 1 = area-preserving)")
    s.add_argument("--blend", type=number(float, 0, 1, hi_open=True), default=0.1,  # = pipeline.DEFAULT_BLEND
                   help="share of the conformal map's area in OT's target measure (0.1; 0 = the paper's measure)")
    s.add_argument("--feature", type=number(float, 0, 100), default=4.0,  # = pipeline.DEFAULT_FEATURE
                   help="extra mass on sharp spots (cone tips, a closed mouth's corners): their masses times 1 + FEATURE "
                        "(4; 0 = the paper's measure)")
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
                   "in the image; auto (default): from the face, found by looking at renders of the surface in any pose "
                   "(without one from the shape: the head template, the opening, a flat cut, the plane it stands on; uncertain "
                   "cases say so), or x, y, z, -x, -y, -z")
    s.add_argument("--no-find-face", dest="find_face", action="store_false",
                   help="with --up auto, do not look for the face (the shape's cues alone)")
    s.add_argument("--no-level", dest="level", action="store_false",
                   help="where a face was found, keep the corners where the boundary puts them (default: turned along the "
                        "boundary until the face's eye line is level in the default image)")
    s.add_argument("--front", default="auto", type=axis(), help="face direction: auto (default: towards the centroid of a --roi mask "
                   "file; without one, the front found with --up auto, or where the mesh faces about a given --up: symmetry "
                   "and detail, as `view` finds it) or an axis (z, -x, ...)")
    s.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto", help="how to open a closed surface")
    s.add_argument("--proxy", type=number(int, 0, 10**8), default=15000, metavar="N",  # = pipeline.DEFAULT_PROXY (kept light: no pipeline import here)
                   help="a scan with more than 1.5 N vertices (with the default N: more than 45,000) is decimated to N vertices for the repair and the maps, and the "
                        "images sample the full surface (default %(default)s; 0: never)")
    s.add_argument("--needles", type=number(float, 0, 0.5, hi_open=True), default=0.01, metavar="RATIO",  # = repair.proxy.NEEDLE_RATIO
                   help="needle triangles: edges shorter than RATIO x their face's longest edge are collapsed for the maps "
                        "(when that merges at least 0.1%% of the vertices) and the images sample the full surface "
                        "(default %(default)s; 0: never)")
    s.set_defaults(func=cmd_convert)

    s = sub.add_parser("reconstruct", help="geometry-image folder -> textured mesh")
    s.add_argument("dir", metavar="GIMAGE_DIR", help="a geometry-image folder `convert` wrote (or one of its aug<k>/)")
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
