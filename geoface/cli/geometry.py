"""``geoface inspect | repair | param | convert | reconstruct | view``."""
from __future__ import annotations

from pathlib import Path

from ..errors import GeofaceError
from .._args import json_to_stdout, write_json
from ..progress import args_quiet

from ._common import guard_outputs, mesh_outputs

_POINT_FILES = (".xyz", ".pts", ".txt")


def _load_surface(path):
    """A mesh file as it is; a point cloud (a PLY/OBJ/OFF without faces, an .xyz) as the surface
    screened Poisson reconstructs from it (:func:`geoface.repair.surface_from_points`)."""
    from ..errors import PointCloudError
    from ..mesh.io import Mesh, load_mesh
    from ..progress import log

    if Path(path).suffix.lower() not in _POINT_FILES:
        try:
            return load_mesh(path)
        except PointCloudError as e:
            log(f"{e}: reconstructing a surface (screened Poisson)")
    from ..repair.points import load_points, surface_from_points

    P, normals = load_points(path)
    s = surface_from_points(P, normals)
    log(f"{Path(path).name}: {s.summary()}")
    return Mesh(s.V, s.F)


# --------------------------------------------------------------------------- inspect
def cmd_inspect(args) -> int:
    from ..mesh.io import load_mesh
    from ..mesh.topology import topology_report

    guard_outputs(args, [args.file], [args.json])
    mesh = load_mesh(args.file)
    rep = topology_report(mesh.V, mesh.F)
    attrs = {
        "uv": mesh.UV is not None,
        "vertex_colors": mesh.colors is not None,
        "texture": None if mesh.texture is None else list(mesh.texture.shape),
    }
    face = _inspect_face(mesh) if args.face and len(mesh.F) else None
    write_json(args, {"file": str(args.file), **rep.to_dict(), "attributes": attrs,
                      **({} if face is None else {"face": face})})
    if not json_to_stdout(args):
        print(f"{args.file}")
        print(rep.format())
        tex = "none" if attrs["texture"] is None else "x".join(map(str, attrs["texture"]))
        print(f"attributes          uv={attrs['uv']}, vertex colours={attrs['vertex_colors']}, texture={tex}")
        if face is not None:
            print(_face_line(face))
    return 0


def _inspect_face(mesh) -> dict:
    """The face found on the mesh by looking (:func:`geoface.track.scan.scan_landmarks`), as JSON:
    found, how sure, the frame, the 68 landmarks in the file's coordinates."""
    from ..errors import MissingDependencyError
    from ..track.scan import scan_landmarks

    try:
        return scan_landmarks(mesh.V, mesh.F).to_dict()
    except MissingDependencyError as e:
        return {"found": False, "why": str(e)}


def _face_line(face: dict) -> str:
    from ..mesh.frame import axis_text

    if not face["found"]:
        return f"face                not found: {face['why']}"
    n = "68 landmarks" if face["source"] == "face mesh" else "the detector's 4 key points (no face mesh)"
    return (f"face                found: {n} from {face['views']} views, score {face['confidence']:.2f}; "
            f"up {axis_text(face['up'], 0.08)}, front {axis_text(face['front'], 0.08)} (--json: the landmarks)")


# --------------------------------------------------------------------------- repair
def cmd_repair(args) -> int:
    from ..mesh.io import save_mesh
    from ..progress import log
    from ..repair import RepairOptions, make_disk

    guard_outputs(args, [args.input], [*mesh_outputs(args.output), args.json])
    mesh = _load_surface(args.input)
    opts = RepairOptions(
        open=args.open,
        up=args.up,
        open_height=args.height,
        cap_area=args.cap_area,
        target_vertices=args.target_vertices,
        min_component_area=args.min_component_area,
        find_face=args.find_face,
    )
    log(f"repairing {args.input}: {len(mesh.V)} vertices, {len(mesh.F)} faces")
    res = make_disk(mesh.V, mesh.F, opts)
    out = mesh.with_geometry(res.V, res.F, res.vertex_map, res.face_map)
    save_mesh(args.output, out, overwrite=args.force)
    write_json(args, {"input": str(args.input), "output": str(args.output), **res.to_dict()})
    if not json_to_stdout(args):
        print(f"{args.input} -> {args.output}")
        print(res.summary())
        print(res.report.format())
    return 0


# --------------------------------------------------------------------------- param
def _parse_corners(text: str | None):
    if not text:
        return None
    try:
        c = [int(x) for x in text.split(",")]
    except ValueError:
        raise GeofaceError(f"--corners must be four vertex indices like 12,40,77,103; got {text!r}") from None
    if len(c) != 4:
        raise GeofaceError(f"--corners needs exactly four vertex indices; got {len(c)}")
    return c


def cmd_param(args) -> int:

    from ..mesh.io import Mesh, load_mesh, save_mesh
    from ..mesh.topology import topology_report
    from ..param import baselines, corners as corner_mod, metrics
    from ..param.ricci import RicciFlowSolver, to_unit_square
    from ..progress import log

    if args.output is not None and Path(args.output).suffix.lower() in (".stl", ".off"):
        raise GeofaceError(f"-o {args.output}: {Path(args.output).suffix} files cannot hold UVs, which are what param "
                           "makes; write .obj, .ply, .glb or .gltf")
    guard_outputs(args, [args.input], [*mesh_outputs(args.output), args.json])
    mesh = load_mesh(args.input)
    V, F = mesh.V, mesh.F
    if args.repair:
        from ..repair import make_disk

        res = make_disk(V, F, up=args.up)
        mesh = mesh.with_geometry(res.V, res.F, res.vertex_map, res.face_map)
        V, F = mesh.V, mesh.F
    rep = topology_report(V, F)
    if not rep.is_disk:
        raise GeofaceError(f"{args.input} is not a topological disk ({rep.components} components, {rep.boundary_loops} boundary loops, genus {rep.genus}); run `geoface repair` first or pass --repair")
    corners = _parse_corners(args.corners)
    if corners is None and args.corner_set is not None:
        sets = corner_mod.corner_sets(V, F, n=8)
        if not 0 <= args.corner_set < len(sets):
            raise GeofaceError(f"--corner-set must be in 0..{len(sets) - 1}; got {args.corner_set}")
        corners = sets[args.corner_set]
    if corners is None:
        corners = corner_mod.default_corners(V, F)
    info = {"input": str(args.input), "output": str(args.output), "method": args.method, "vertices": int(len(V)), "faces": int(len(F))}
    log(f"param: {args.method} on {len(V)} vertices")
    if args.method == "ricci":
        solver = RicciFlowSolver(V, F, tolerance=args.tolerance)
        r = solver.solve(corners)
        if not r.converged:
            raise GeofaceError(f"Ricci flow did not converge (max |K - target| = {r.residual:.3g} after {r.iterations} iterations)")
        colors = mesh.colors
        if len(r.V) > len(V):  # boundary edges split by the flow
            from ..pipeline import extend_split

            V, _, colors = extend_split(r.V, r.split_edges, len(V), None, colors)
            mesh = Mesh(V, r.mesh_F, colors=colors)
        F = r.F
        uv = to_unit_square(r.uv, r.width, r.height, args.fit)
        info.update(iterations=r.iterations, residual=r.residual, seconds=r.seconds, aspect=r.aspect, fit=args.fit,
                    corners=[int(c) for c in r.corners],
                    ears_flipped=r.ears_flipped, intrinsic_flips=r.intrinsic_flips, split_boundary_edges=int(len(r.split_edges)))
        # the conformal map itself (projective per triangle / per piece after intrinsic flips)
        info["conformal_map_distortion"] = metrics.map_distortion(r.V, r.mesh_F, r.map_points, level=2).summary()
    elif args.method == "harmonic":
        uv, t = baselines.timed(baselines.harmonic_rectangle, V, F, corners)
        info.update(seconds=t, corners=[int(c) for c in corners])
    else:
        uv, t = baselines.timed(baselines.lscm, V, F)
        lo, hi = uv.min(0), uv.max(0)
        uv = (uv - lo) / (hi - lo).max()
        info.update(seconds=t)
    d = metrics.distortion(V, F, uv).summary()
    info["distortion"] = d
    out = Mesh(V, F, UV=uv, FUV=F, colors=mesh.colors, texture=None)
    save_mesh(args.output, out, overwrite=args.force)
    write_json(args, info)
    if json_to_stdout(args):
        return 0
    print(f"{args.input} -> {args.output}  ({args.method}, {info['seconds']:.2f} s)")
    print(
        f"  quasi-conformal ratio: mean {d['qc_mean']:.4f}, p95 {d['qc_p95']:.4f}, max {d['qc_max']:.3g}; "
        f"|log area ratio| mean {d['log_area_abs_mean']:.3f}; flipped triangles {d['flipped']}"
    )
    if args.method == "ricci":
        print(f"  Newton iterations {info['iterations']}, max |K - target| {info['residual']:.2e}, rectangle aspect {info['aspect']:.4f}")
        c = info["conformal_map_distortion"]
        extra = f"; {r.intrinsic_flips} intrinsic flips, {len(r.split_edges)} boundary edges split" if r.intrinsic_flips else ""
        print(f"  conformal map (sampled): quasi-conformal mean {c['qc_mean']:.4f}, p95 {c['qc_p95']:.4f}; folded triangles {c['flipped']}{extra}")
    return 0


# --------------------------------------------------------------------------- convert / reconstruct
def _convert_summary(args, out, m) -> str:
    """The one line `convert` ends with: what was written, how long, the frame, the quality."""
    sets = m["sets"]
    n = len(sets)
    line = f"{args.input} -> {out}/: {n} image set{'s' if n != 1 else ''} at {args.res}x{args.res} in {m['seconds']['total']:.1f} s"
    if "proxy" in m:
        line += (f" (maps on a {m['proxy']['proxy_vertices']:,}-vertex proxy of the {m['proxy']['scan_vertices']:,}"
                 + (", needles merged)" if m["proxy"].get("kind") == "needles merged" else ")"))
    fr = m.get("frame")
    if fr is not None:
        import re

        how = re.sub(r"\s*\([^()]*\)", "", fr["how"].split(";")[0])
        from ..mesh.frame import axis_text

        # an axis name only for an exact axis (the frame snapped to the file's axes)
        line += f"; up {axis_text(fr['up'], 0.08)}, front {axis_text(fr['front'], 0.08)} ({how})"
    line += f"; {sum(st['distortion']['flipped'] for st in sets)} flipped"
    shares = [st["roi_pixel_share"] for st in sets if "roi_pixel_share" in st]
    if shares:
        lo, hi = 100 * min(shares), 100 * max(shares)
        line += f"; face {lo:.0f}% of the pixels" if round(lo) == round(hi) else f"; face {lo:.0f}-{hi:.0f}% of the pixels"
    hd = [st["reconstruction"]["hausdorff"] for st in sets if "reconstruction" in st]
    if hd:
        line += f"; Hausdorff {100 * max(hd):.2f}% of the diagonal" + (" (worst set)" if n > 1 else "")
    if any(not st.get("ot", {}).get("converged", True) for st in sets):
        line += "; OT stopped short of --ot-tol (metrics.json: ot.residual)"
    return line


def _convert_details(args, m) -> None:
    """Per corner set (``-v``): distortion, pixels, error and the path the map took."""
    fr = m.get("frame")
    if fr is not None:
        up = ", ".join(f"{x:.2f}" for x in fr["up"])
        front = ", ".join(f"{x:.2f}" for x in fr["front"])
        print(f"  frame: up ({up}), front ({front}): {fr['kind']}, {fr['how']}")
    for st in m["sets"]:
        d = st["distortion"]
        line = f"  set {st['corner_set']}: |log area| mean {d['log_area_abs_mean']:.3f}, QC mean {d['qc_mean']:.2f}, flipped {d['flipped']}"
        if "roi_pixel_share" in st:
            line += f", ROI pixels {100 * st['roi_pixel_share']:.1f}%"
        if "reconstruction" in st:
            line += f", Hausdorff {100 * st['reconstruction']['hausdorff']:.3f}% of the diagonal"
        print(line)
        if "ot" in st:
            ot = st["ot"]
            sites = "conformal sites" if ot["sites"] == "conformal" else "sites from an area-balanced embedding"
            if ot["path"] == "balanced":
                how = "the area-balanced embedding (OT from it did not come closer)"
            elif ot["path"].endswith("convex-combination"):
                how = (f"OT centroids ({sites}), {ot['flipped_before']} folded triangles replaced by the fold-free step "
                       f"({ot['fitted_vertices']} vertices re-fitted, mean |log cell-area error| "
                       f"{ot['area_error_before']:.3f} -> {ot['area_error_after']:.3f})")
            else:
                how = f"OT centroids as they are ({sites}, no fold)"
            reached = "" if ot["converged"] else f"; tolerance reached {ot['residual']:.2g} (asked {args.ot_tol:g})"
            print(f"    map: {how}; {ot['iterations']} Newton steps, {ot['power_diagrams']} power diagrams{reached}")


def cmd_convert(args) -> int:
    from ..pipeline import ConvertOptions, convert, load_roi

    out = Path(args.output)
    inp = Path(args.input)
    if args.corner_set is not None and args.augment != 1:
        raise GeofaceError(f"--corner-set {args.corner_set} converts one corner set; --augment {args.augment} asks for "
                           f"{args.augment}: give one of them")
    roi_file = None if args.roi in ("face", "none") else args.roi
    guard_outputs(args, [inp, roi_file], [out])
    mesh = _load_surface(inp)
    roi = args.roi
    if roi not in ("face", "none"):
        roi = load_roi(roi, len(mesh.V))
    opts = ConvertOptions(res=args.res, roi=roi, lam=args.lam, blend=args.blend, feature=args.feature, augment=args.augment,
                          method=args.method, ot_tol=args.ot_tol, smooth=args.smooth, up=args.up, open=args.open, front=args.front,
                          corner_set=args.corner_set, reconstruct=args.reconstruct, proxy=args.proxy,
                          needles=args.needles, find_face=args.find_face, level=args.level)
    m = convert(mesh, out, opts, overwrite=args.force)
    print(_convert_summary(args, out, m))
    from .. import progress as _progress

    fr = m.get("frame")
    if fr is not None and not fr["certain"]:
        print(f"  which way is up is uncertain ({fr['why']}): check preview.png, or pass --up / --front")
    if _progress.VERBOSE:
        _convert_details(args, m)
    for f in m.get("failed_sets", []):
        print(f"  set {f['corner_set']}: FAILED and skipped: {f['error']}")
    return 0


def cmd_reconstruct(args) -> int:
    from ..gimage import load_gimage, reconstruct, save_reconstruction

    guard_outputs(args, [args.dir], mesh_outputs(args.output))
    gi = load_gimage(args.dir)
    mesh = reconstruct(gi, smooth=args.smooth)
    save_reconstruction(args.output, mesh, gi, overwrite=args.force)
    print(f"{args.dir} -> {args.output}: {len(mesh.V)} vertices, {len(mesh.F)} faces")
    return 0


# --------------------------------------------------------------------------- view
def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().replace("x", ",").split(","))
    except ValueError:
        raise GeofaceError(f"--size must look like 1024,768; got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise GeofaceError(f"--size must be between 16 and 8192 pixels per side; got {text!r}")
    return w, h


def _view_face(args, path: Path, n_vertices: int):
    """The face mask of a mesh from --meta (or MESH.json beside it), when there is one."""
    import json

    meta = Path(args.meta) if args.meta else path.with_suffix(".json")
    if not meta.is_file():
        if args.meta:
            raise GeofaceError(f"--meta: no such file {meta}")
        return None
    try:
        d = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        if args.meta:
            raise GeofaceError(f"--meta {meta}: not JSON ({e})") from None
        return None
    face = d.get("face_mask") if isinstance(d, dict) else None
    if not face:
        if args.meta:
            raise GeofaceError(f"--meta {meta}: no face_mask in it")
        return None
    if max(face) >= n_vertices:
        raise GeofaceError(f"--meta {meta}: its face mask indexes {max(face) + 1} vertices; the mesh has {n_vertices}")
    return face


def _view_web(args) -> int:
    from ..webview import WebView

    if args.screenshot or args.turntable or args.uv_distortion:
        raise GeofaceError("--web shows an interactive page; --screenshot, --turntable and --uv-distortion are for "
                           "off-screen pictures (the page has a UV-distortion colouring of its own)")
    if args.html:
        from .._io import atomic_write_text

        guard_outputs(args, [p for p in args.file if Path(p).is_file()], [args.html])
        view = WebView(args.file, host="127.0.0.1", port=0, up=args.up, drive=args.drive, fps=args.fps, quiet=True)
        try:
            page = view.html()
        finally:
            view.stop()
        atomic_write_text(args.html, page)
        print(f"{', '.join(map(str, args.file))} -> {args.html}  (one self-contained page: open it from disk)")
        return 0
    view = WebView(args.file, host=args.host, port=args.port, up=args.up, drive=args.drive, fps=args.fps,
                   quiet=True)
    print(f"geoface view: {view.url}  (open it in a browser; Ctrl-C stops the server)", flush=True)
    view.serve(exit_after=args.exit_after, idle_exit=args.idle_exit)
    return 0


def cmd_view(args) -> int:
    from .. import viz

    if args.html and not str(args.html).lower().endswith((".html", ".htm")):
        raise GeofaceError(f"--html: an .html path; got {args.html}")
    if args.web or args.html:
        return _view_web(args)
    if len(args.file) != 1:
        raise GeofaceError("several paths are shown side by side with --web; off-screen, give one path")
    if args.drive or args.exit_after or args.idle_exit:
        raise GeofaceError("--drive, --exit-after and --idle-exit belong to --web")
    if args.screenshot and args.turntable:
        raise GeofaceError("choose --screenshot or --turntable")
    size = _parse_size(args.size)
    shot, movie = args.screenshot, args.turntable
    if shot is None and movie is None and not viz.has_display():
        raise GeofaceError("no display to open a window on; pass --screenshot OUT.png (or --turntable OUT.mp4, "
                           "or --web) to look at it another way")
    if movie is not None and Path(movie).suffix.lower() != ".mp4":
        raise GeofaceError(f"--turntable: an .mp4 path; got {movie}")
    if shot is not None and Path(shot).suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise GeofaceError(f"--screenshot: a .png or .jpg path; got {shot}")
    path = Path(args.file[0])
    if shot is not None or movie is not None:
        guard_outputs(args, [path, getattr(args, "meta", None)], [shot or movie])
    from ..webview.items import item_kind

    if path.is_file() and item_kind(path) == "splat":  # Gaussian splats: our rasterizer, off-screen
        if movie is None:
            raise GeofaceError(f"{path} holds Gaussian splats: look at them with --turntable OUT.mp4 or --web")
        from ..drive.avatars import splat_turntable
        from ..splat.ply import load_ply

        n = splat_turntable(load_ply(path), movie, seconds=args.seconds, size=size, up=args.up, quiet=args_quiet(args))
        print(f"{args.file[0]} -> {movie}  (turntable of the splats, {n} frames, {size[0]}x{size[1]})")
        return 0
    if path.is_dir() and not (path / "meta.json").exists() and (path / "aug0" / "meta.json").exists():
        path = path / "aug0"  # `geoface convert --augment K` writes one image set per corner set
    if path.is_dir():
        from ..gimage import load_gimage, reconstruct

        gi = load_gimage(path)
        if args.uv_distortion:
            raise GeofaceError("--uv-distortion needs a mesh with UVs; a geometry-image folder has none to measure")
        mesh, face = reconstruct(gi), None
        shown = [m for m in ("position", "normal", "texture") if gi.has(m)] + ["mask", "surface"]
        what = f"geometry image {gi.resolution}x{gi.resolution}: {' | '.join(shown)}"
        if shot is not None:
            img = viz.gimage_montage(gi, surface=True, screenshot=shot, tile=size[1])
            size = (img.shape[1], img.shape[0])
        elif movie is None:  # interactive: the surface the images encode, textured
            viz.plot_mesh(mesh, window_size=size, view=args.view, up=args.up)
    else:
        from ..mesh.io import load_mesh

        mesh = load_mesh(path)
        face = _view_face(args, path, len(mesh.V))
        if args.uv_distortion:
            if mesh.UV is None:
                raise GeofaceError(f"{path} has no UVs; --uv-distortion needs a parameterized mesh (see `geoface param`)")
            if movie is not None:
                raise GeofaceError("--turntable turns around the surface; --uv-distortion shows the flat UV layout")
            V2, F2, uv2, _ = viz.split_corner_uvs(mesh.V, mesh.F, mesh.UV, mesh.FUV)  # seams: one vertex per UV
            viz.plot_uv_distortion(V2, F2, uv2, metric=args.metric, screenshot=shot, window_size=size)
            what = f"UV {args.metric} distortion"
        elif movie is None:
            viz.plot_mesh(mesh, screenshot=shot, window_size=size, view=args.view, up=args.up, face=face)
            what = ("textured mesh" if mesh.texture is not None and mesh.UV is not None else "mesh") + f", {args.view} view"
    if movie is not None:
        n = viz.turntable(mesh, movie, seconds=args.seconds, window_size=size, up=args.up, face=face, quiet=args_quiet(args))
        print(f"{args.file[0]} -> {movie}  (turntable, {n} frames, {size[0]}x{size[1]})")
    elif shot is not None:
        print(f"{args.file[0]} -> {shot}  ({what}, {size[0]}x{size[1]})")
    return 0
