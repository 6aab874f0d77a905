"""The ``geoface`` command: thin subcommands that parse, call one library function, report.

Bad input never produces a traceback: every :class:`~geoface.GeofaceError` (and file
system error) becomes one line on stderr and exit code 2.  Outputs are written
atomically, and an input file is never overwritten.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from . import __version__
from .errors import GeofaceError, GeofaceWarning, InvalidMeshError
from ._args import SEED, add_json, json_to_stdout, number, write_json


#: options whose value may be a negative axis ("--up -z"), which argparse would take for a flag
_AXIS_OPTIONS = ("--up", "--front")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2 (argparse's own code for usage errors)
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):
        import sys

        args = list(sys.argv[1:] if args is None else args)
        out, k = [], 0
        while k < len(args):  # "--up -z" -> "--up=-z"
            if args[k] in _AXIS_OPTIONS and k + 1 < len(args) and args[k + 1] in ("-x", "-y", "-z"):
                out.append(f"{args[k]}={args[k + 1]}")
                k += 2
            else:
                out.append(args[k])
                k += 1
        return super().parse_known_args(out, namespace)


def _mesh_outputs(path) -> list:
    """A mesh output with the companion files written with it (OBJ: .mtl, texture, normal map)."""
    if path is None:
        return []
    from .mesh.io import companion_names

    return [path, *companion_names(path)]


def _guard(args, inputs, outputs, resumable=()) -> None:
    """The output-path policy (geoface._io.check_outputs), before any work.  An input mesh
    counts with the files it references (its MTL, texture, normal map)."""
    from ._io import check_outputs
    from .mesh.io import companion_names

    ins = []
    for p in inputs:
        if p is None:
            continue
        ins.append(p)
        if Path(p).is_file():
            ins += [c for c in companion_names(p) if c.exists()]
    outputs = [o for o in outputs if o is not None and o != "-"]  # "--json -": stdout
    check_outputs(ins, outputs, force=getattr(args, "force", False), resumable=resumable)


#: the neural commands' inputs and outputs (argument names), for the output-path policy;
#: the geometry commands apply it in their own functions (they know their companion files)
_PATHS = {
    ("ddpm", "train"): (("data_dir",), ("output",)),
    ("ddpm", "sample"): (("run_dir",), ("output",)),
    ("texture", "synth"): ((), ("output",)),
    ("texture", "train"): (("data_dir",), ("output",)),
    ("texture", "reconstruct"): (("photo", "model", "mesh", "camera"), ("output",)),
    ("splat", "fit"): (("mesh",), ("output", "renders")),
    ("hmd", "synth"): ((), ("output",)),
    ("hmd", "train"): (("reg_dir",), ("output",)),
    ("hmd", "remove"): (("model_dir", "usage_dir"), ("output",)),
    ("hmd", "eval"): (("model_dir", "usage_dir"), ("json",)),
    ("talk", "synth"): ((), ("output",)),
    ("talk", "train"): (("data_dir",), ("output",)),
    ("talk", "animate"): (("model_dir", "audio", "poses"), ("output",)),
    ("talk", "eval"): (("model_dir", "data_dir"), ("json",)),
}


def _guard_by_table(args) -> None:
    """The output-path policy for the commands in :data:`_PATHS`.  A DDPM run folder with a
    checkpoint is resumed with ``--resume``; model folders the command refuses to replace on
    its own terms (hmd, talk) are left to it."""
    key = (getattr(args, "command", None), getattr(args, "what", None))
    if key not in _PATHS:
        return
    ins, outs = _PATHS[key]
    inputs = [getattr(args, a, None) for a in ins]
    outputs = [getattr(args, a, None) for a in outs]
    resumable = []
    if key == ("ddpm", "train") and getattr(args, "resume", False):
        resumable = outputs
    if key[0] in ("hmd", "talk") and key[1] in ("train", "remove", "animate"):
        resumable = outputs  # these check their model/frames folders themselves (--force)
    _guard(args, inputs, outputs, resumable=resumable)


# --------------------------------------------------------------------------- inspect
def cmd_inspect(args) -> int:
    from .mesh.io import load_mesh
    from .mesh.topology import topology_report

    _guard(args, [args.file], [args.json])
    mesh = load_mesh(args.file)
    rep = topology_report(mesh.V, mesh.F)
    attrs = {
        "uv": mesh.UV is not None,
        "vertex_colors": mesh.colors is not None,
        "texture": None if mesh.texture is None else list(mesh.texture.shape),
    }
    write_json(args, {"file": str(args.file), **rep.to_dict(), "attributes": attrs})
    if not json_to_stdout(args):
        print(f"{args.file}")
        print(rep.format())
        tex = "none" if attrs["texture"] is None else "x".join(map(str, attrs["texture"]))
        print(f"attributes          uv={attrs['uv']}, vertex colours={attrs['vertex_colors']}, texture={tex}")
    return 0


# --------------------------------------------------------------------------- repair
def cmd_repair(args) -> int:
    from .mesh.io import load_mesh, save_mesh
    from .progress import log
    from .repair import RepairOptions, make_disk

    _guard(args, [args.input], [*_mesh_outputs(args.output), args.json])
    mesh = load_mesh(args.input)
    opts = RepairOptions(
        open=args.open,
        up=args.up,
        open_height=args.height,
        cap_area=args.cap_area,
        target_vertices=args.target_vertices,
        min_component_area=args.min_component_area,
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

    from .mesh.io import Mesh, load_mesh, save_mesh
    from .mesh.topology import topology_report
    from .param import baselines, corners as corner_mod, metrics
    from .param.ricci import RicciFlowSolver, to_unit_square
    from .progress import log

    _guard(args, [args.input], [*_mesh_outputs(args.output), args.json])
    mesh = load_mesh(args.input)
    V, F = mesh.V, mesh.F
    if args.repair:
        from .repair import make_disk

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
            from .pipeline import _extend_split

            V, _, colors = _extend_split(r.V, r.split_edges, len(V), None, colors)
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


# --------------------------------------------------------------------------- synth
def _parse_expression(text: str | None) -> dict:
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise InvalidMeshError(f"expression items look like name=value; got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InvalidMeshError(f"expression value for {k.strip()!r} is not a number: {v!r}") from None
    return out


def cmd_synth_head(args) -> int:
    from .mesh.io import Mesh, save_mesh
    from .synth.head import procedural_head

    _guard(args, [], [*_mesh_outputs(args.output), args.meta])
    head = procedural_head(
        n_vertices=args.vertices, seed=args.seed, expression=_parse_expression(args.expression) or None, texture_size=args.texture_size
    )
    ext = Path(args.output).suffix.lower()
    if ext in (".obj", ".glb", ".gltf"):
        mesh = Mesh.from_vertex_uv(head.V, head.F, head.UV, texture=head.texture)
    else:
        mesh = Mesh(head.V, head.F, colors=head.colors)
    save_mesh(args.output, mesh, overwrite=args.force)
    if args.meta:
        from ._io import atomic_write_text

        meta = {
            "seed": head.seed,
            "identity": head.identity.to_dict(),
            "expression": head.expression.to_dict(),
            "eye_line_y": float(head.eye_line_y),
            "landmarks": {k: int(v) for k, v in head.landmarks.items()},
            "face_mask": [int(i) for i in head.face_mask.nonzero()[0]],
        }
        atomic_write_text(args.meta, json.dumps(meta, indent=1))
    print(f"wrote {args.output}: {len(head.V)} vertices, {len(head.F)} faces (seed {head.seed})")
    return 0


def cmd_synth_ict(args) -> int:
    from .mesh.io import Mesh, save_mesh
    from .synth.ict import load_ict_model

    _guard(args, [args.model], [*_mesh_outputs(args.output), args.meta])
    model = load_ict_model(args.model)
    parts = tuple(p.strip() for p in args.parts.split(",") if p.strip())
    identity = args.seed if args.identity is None else _parse_weights(args.identity)
    head = model.head(identity, _parse_expression(args.expression), parts, n_identity=args.n_identity)
    save_mesh(args.output, Mesh(head.V, head.F, UV=head.UV, FUV=head.FUV), overwrite=args.force)
    if args.meta:
        from ._io import atomic_write_text

        atomic_write_text(args.meta, json.dumps({**head.meta(), "seed": None if args.identity else args.seed}, indent=1))
    expr = ", ".join(f"{k}={v:g}" for k, v in head.expression.items()) or "neutral"
    print(f"wrote {args.output}: {len(head.V)} vertices, {len(head.F)} faces ({', '.join(head.parts)}; "
          f"identity {'weights' if args.identity else f'seed {args.seed}'}; {expr})")
    return 0


def _parse_weights(text: str) -> list:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise GeofaceError(f"--identity must be comma-separated numbers; got {text!r}") from None


def cmd_synth_pack_ict(args) -> int:
    from .synth.ict import load_ict_model, pack_ict

    _guard(args, [args.clone], [args.output])
    out = pack_ict(args.clone, args.output, overwrite=args.force, quiet=bool(args.quiet))
    m = load_ict_model(out)
    print(f"wrote {out}: {len(m.vertices)} vertices, {m.n_identities} identity modes, {len(m.expression_names)} "
          f"expressions, regions {', '.join(m.available_regions)} ({out.stat().st_size / 2**20:.1f} MB)")
    return 0


#: synth surface --resolution: up to ~4M triangles
MAX_SURFACE_RESOLUTION = 2048

SURFACES = ("square", "disk", "flat-irregular", "cap", "hemisphere", "sphere", "cylinder", "torus", "genus2", "mobius")


def cmd_synth_surface(args) -> int:
    from .mesh.io import save_mesh
    from .synth import surfaces as S

    _guard(args, [], _mesh_outputs(args.output))
    n = args.resolution
    if not 2 <= n <= MAX_SURFACE_RESOLUTION:
        raise GeofaceError(f"--resolution must be in 2..{MAX_SURFACE_RESOLUTION}; got {n}")
    make = {
        "square": lambda: S.square_grid(n),
        "disk": lambda: S.disk_grid(max(n // 2, 1)),
        "flat-irregular": lambda: S.irregular_flat_patch(n * n, seed=args.seed),
        "cap": lambda: S.spherical_cap(1.0, 1.0, max(n // 2, 1)),
        "hemisphere": lambda: S.hemisphere(1.0, max(n // 2, 1)),
        "sphere": lambda: S.sphere(1.0, max(min(n // 8, 6), 1)),
        "cylinder": lambda: S.cylinder(1.0, 2.0, 2 * n, n),
        "torus": lambda: S.torus(1.0, 0.3, 2 * n, n),
        "genus2": lambda: S.genus2(max(n * 2, 16)),
        "mobius": lambda: S.mobius_strip(2 * n, max(n // 4, 2)),
    }[args.name]
    V, F = make()
    save_mesh(args.output, V=V, F=F, overwrite=args.force)
    print(f"wrote {args.output}: {args.name}, {len(V)} vertices, {len(F)} faces")
    return 0


# --------------------------------------------------------------------------- convert / reconstruct
def cmd_convert(args) -> int:
    from .mesh.io import load_mesh
    from .pipeline import ConvertOptions, convert, load_roi

    out = Path(args.out_dir)
    inp = Path(args.input)
    roi_file = None if args.roi in ("face", "none") else args.roi
    _guard(args, [inp, roi_file], [out])
    mesh = load_mesh(inp)
    roi = args.roi
    if roi not in ("face", "none"):
        roi = load_roi(roi, len(mesh.V))
    opts = ConvertOptions(res=args.res, roi=roi, lam=args.lam, augment=args.augment, method=args.method,
                          ot_tol=args.ot_tol, smooth=args.smooth, up=args.up, open=args.open, front=args.front,
                          corner_set=args.corner_set)
    m = convert(mesh, out, opts, overwrite=args.force)
    print(f"{args.input} -> {out}/  ({len(m['sets'])} image set(s) at {args.res}x{args.res}, {m['seconds']['total']:.1f} s)")
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
            how = ("OT centroids as they are (no fold)" if ot["path"] == "ot" else
                   f"OT centroids, {ot['flipped_before']} folded triangles replaced by the fold-free step "
                   f"({ot['fitted_vertices']} vertices re-fitted, mean |log cell-area error| "
                   f"{ot['area_error_before']:.3f} -> {ot['area_error_after']:.3f})")
            print(f"    map: {how}; {ot['iterations']} Newton steps, {ot['power_diagrams']} power diagrams")
    for f in m.get("failed_sets", []):
        print(f"  set {f['corner_set']}: FAILED and skipped: {f['error']}")
    return 0


def cmd_reconstruct(args) -> int:
    from .gimage import load_gimage, reconstruct, save_reconstruction

    _guard(args, [args.dir], _mesh_outputs(args.output))
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


def cmd_view(args) -> int:
    from . import viz

    size = _parse_size(args.size)
    shot = args.screenshot
    if shot is None and not viz.has_display():
        raise GeofaceError("no display to open a window on; pass --screenshot OUT.png to render off-screen")
    if shot is not None:
        _guard(args, [args.file], [shot])
    path = Path(args.file)
    if path.is_dir() and not (path / "meta.json").exists() and (path / "aug0" / "meta.json").exists():
        path = path / "aug0"  # `geoface convert --augment K` writes one image set per corner set
    if path.is_dir():
        from .gimage import load_gimage

        gi = load_gimage(path)
        if args.uv_distortion:
            raise GeofaceError("--uv-distortion needs a mesh with UVs; a geometry-image folder has none to measure")
        what = f"geometry image {gi.resolution}x{gi.resolution}: position | normal | texture | mask | surface"
        if shot is None:  # interactive: the surface the images encode, textured
            from .gimage import reconstruct

            viz.plot_mesh(reconstruct(gi), window_size=size)
        else:
            img = viz.gimage_montage(gi, surface=True, screenshot=shot, tile=size[1])
            size = (img.shape[1], img.shape[0])
    else:
        from .mesh.io import load_mesh

        mesh = load_mesh(path)
        if args.uv_distortion:
            if mesh.UV is None:
                raise GeofaceError(f"{args.file} has no UVs; --uv-distortion needs a parameterized mesh (see `geoface param`)")
            V2, F2, uv2, _ = viz.split_corner_uvs(mesh.V, mesh.F, mesh.UV, mesh.FUV)  # seams: one vertex per UV
            viz.plot_uv_distortion(V2, F2, uv2, metric=args.metric, screenshot=shot, window_size=size)
            what = f"UV {args.metric} distortion"
        else:
            viz.plot_mesh(mesh, screenshot=shot, window_size=size)
            what = "textured mesh" if mesh.texture is not None and mesh.UV is not None else "mesh"
    if shot is not None:
        print(f"{args.file} -> {shot}  ({what}, {size[0]}x{size[1]})")
    return 0


# --------------------------------------------------------------------------- main
def _dataset_options(b) -> None:
    """The conversion and scheduling flags that ``dataset build`` and ``dataset ict`` share."""
    b.add_argument("--res", type=number(int, 4, 8192), default=512, help="image resolution N (default 512)")
    b.add_argument("--augment", type=number(int, 1, 8), default=8, help="corner sets per mesh, 1..8 (default 8)")
    b.add_argument("--workers", type=number(int, 1, 1024), default=None, help="local worker processes (default: the number of cores; 1 = serial)")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a Dask scheduler (tcp://host:port) instead of the local pool")
    b.add_argument("--lam", type=number(float, 0, 1000, lo_open=True), default=2.5, help="mass factor on the ROI (2.5)")
    b.add_argument("--method", choices=["ot", "conformal"], default="ot")
    b.add_argument("--ot-tol", type=number(float, 0, 1, lo_open=True, hi_open=True), default=1e-3)
    b.add_argument("--reconstruct", action="store_true", help="also write reconstruction.obj and its error")
    b.add_argument("--retry-failed", action="store_true", help="try items that failed in an earlier run again")
    b.add_argument("--strict", action="store_true", help="exit code 1 when any item failed")
    b.add_argument("--up", default="y")
    b.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto")


def _dataset_report(args, out: Path, s: dict) -> int:
    print(f"{out}/: {s['done']} items built, {s['failed']} failed, {s['skipped']} skipped "
          f"({s['seconds']:.1f} s, {s['items_per_minute']:.1f} items/min); manifest {out / 'manifest.jsonl'}")
    for item, err in s["failures"].items():
        print(f"  failed {item}: {err}")
    return 1 if (args.strict and s["failed"]) else 0


def _dataset_opts(args):
    from .dataset import DatasetOptions

    return DatasetOptions(res=args.res, augment=args.augment, roi=args.roi, lam=args.lam, method=args.method,
                          ot_tol=args.ot_tol, reconstruct=args.reconstruct, up=args.up, open=args.open)


def cmd_dataset_build(args) -> int:
    from .dataset import build_dataset

    out, inp = Path(args.out_dir), Path(args.in_dir)
    # an existing dataset folder is resumed (its manifest records the options it was built with)
    _guard(args, [inp, args.labels], [out], resumable=[out] if (out / "manifest.jsonl").is_file() else [])
    s = build_dataset(inp, out, _dataset_opts(args), workers=args.workers, scheduler=args.scheduler, labels=args.labels,
                      retry_failed=args.retry_failed, rebuild=args.force)
    return _dataset_report(args, out, s)


def cmd_dataset_ict(args) -> int:
    from .dataset import build_ict_dataset

    out = Path(args.out_dir)
    _guard(args, [args.model], [out], resumable=[out] if (out / "manifest.jsonl").is_file() else [])
    s = build_ict_dataset(out, args.count, _dataset_opts(args), seed=args.seed, model=args.model, mix_share=args.mix_share,
                          heldout_share=args.heldout_share, workers=args.workers, scheduler=args.scheduler,
                          retry_failed=args.retry_failed, rebuild=args.force)
    return _dataset_report(args, out, s)


def _verbs(parser, common):
    """Second-level subcommands (``geoface synth head``); each accepts the common flags (-q)."""
    sp = parser.add_subparsers(dest="what", metavar="WHAT", parser_class=_Parser)
    sp.required = True
    add = sp.add_parser
    sp.add_parser = lambda *a, **k: add(*a, parents=[common], **k)
    return sp


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="geoface", description="Geometry processing of head and face meshes.")
    p.add_argument("--version", action="version", version=f"geoface {__version__}")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress output")
    common.add_argument("--force", action="store_true", default=argparse.SUPPRESS,
                        help="replace outputs that exist (never an input)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
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
    s.add_argument("--up", default="y", help="up axis: x, y, z, -x, -y, -z (default y)")
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
    s.add_argument("--up", default="y", help="up axis for --repair")
    add_json(s, "the metrics")
    s.set_defaults(func=cmd_param)

    s = sub.add_parser("convert", help="mesh -> geometry images (+ reconstruction, preview, metrics)")
    s.add_argument("input")
    s.add_argument("out_dir")
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
    s.add_argument("--up", default="y", help="up axis: x, y, z, -x, -y, -z (default y): where closed heads are cut open, "
                   "and which way the face is upright in the image; auto: from the opening of a surface already open "
                   "(the neck), else y")
    s.add_argument("--front", default="auto", help="face direction: auto (default: towards the centroid of a --roi mask "
                   "file, +z without one) or an axis (z, -x, ...)")
    s.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto", help="how to open a closed surface")
    s.set_defaults(func=cmd_convert)

    s = sub.add_parser("reconstruct", help="geometry-image folder -> textured mesh")
    s.add_argument("dir")
    s.add_argument("-o", "--output", required=True, help="output mesh (obj writes .mtl, texture and normal map too)")
    s.add_argument("--smooth", type=number(int, 0, 1000), default=0, help="Laplacian smoothing iterations")
    s.set_defaults(func=cmd_reconstruct)

    s = sub.add_parser("view", help="show a mesh or geometry-image folder (or render it to a PNG)")
    s.add_argument("file", help="a mesh file, or a geometry-image folder written by `geoface convert`")
    s.add_argument("--screenshot", default=None, metavar="OUT.png", help="render off-screen to this PNG and exit")
    s.add_argument("--uv-distortion", action="store_true", help="show the UV layout coloured by distortion (mesh with UVs)")
    s.add_argument("--metric", choices=["qc", "area"], default="qc", help="distortion measure for --uv-distortion (qc)")
    s.add_argument("--size", default="1024,768", metavar="W,H",
                   help="window / picture size in pixels (1024,768); for a geometry-image montage H is the tile size")
    s.set_defaults(func=cmd_view)

    s = sub.add_parser("dataset", help="build geometry-image datasets from folders of meshes")
    dv = _verbs(s, common)
    b = dv.add_parser("build", help="every mesh x corner set -> a geometry-image folder (resumable, parallel)")
    b.add_argument("in_dir", help="folder of meshes (optional <stem>.json face masks, labels.jsonl)")
    b.add_argument("out_dir")
    b.add_argument("--labels", default=None, help="labels/prompts per mesh stem (.jsonl or .json; default IN_DIR/labels.jsonl)")
    b.add_argument("--roi", choices=["auto", "face", "none"], default="auto", help="auto: <stem>.json face mask when present, else the face cone")
    _dataset_options(b)
    b.set_defaults(func=cmd_dataset_build)
    b = dv.add_parser("ict", help="labelled real heads of the ICT-FaceKit model -> geometry images (resumable, parallel)")
    b.add_argument("out_dir")
    b.add_argument("--count", type=number(int, 1, 10_000_000), required=True, help="number of heads (one identity each)")
    b.add_argument("--seed", type=SEED, default=0, help="draws identities, expressions, prompts and the split")
    b.add_argument("--model", default=None, help="the ICT-FaceKit model (.npz or a clone; default: the copy shipped with geoface)")
    b.add_argument("--mix-share", type=number(float, 0, 1), default=0.3, help="share of random ARKit mixes (the rest: named presets)")
    b.add_argument("--heldout-share", type=number(float, 0, 1), default=0.2, help="share of identities labelled split=heldout")
    b.add_argument("--roi", choices=["auto", "face", "none"], default="auto", help="auto: the model's face area")
    _dataset_options(b)
    b.set_defaults(func=cmd_dataset_ict)

    from .learn.cli import register as register_ddpm  # argparse only: torch loads inside the commands
    from .learn.texture_cli import register as register_texture

    register_ddpm(sub, common)

    from .splat.cli import register as register_splat  # argparse only: torch loads inside the command

    register_splat(sub, common)
    from .splat.hfm_cli import register as register_hmd

    register_hmd(sub, common)
    from .splat.thgs_cli import register as register_talk

    register_talk(sub, common)
    register_texture(sub, common)

    s = sub.add_parser("synth", help="write procedural test geometry")
    ss = _verbs(s, common)
    h = ss.add_parser("head", help="the procedural expressive head")
    h.add_argument("-o", "--output", required=True)
    h.add_argument("--vertices", type=number(int, 1000, 200_000), default=20000)
    h.add_argument("--seed", type=SEED, default=0)
    h.add_argument("--expression", default=None, help="e.g. smile=0.8,jaw_open=0.3")
    h.add_argument("--texture-size", type=number(int, 16, 8192), default=512)
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
    a.add_argument("--resolution", type=number(int, 2, 2048), default=24)
    a.add_argument("--seed", type=SEED, default=0)
    a.set_defaults(func=cmd_synth_surface)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # a usage error (one line already printed), --help or --version
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    if not hasattr(args, "force"):
        args.force = False
    from .progress import set_quiet

    if args.quiet:
        set_quiet(True)
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
            _guard_by_table(args)
            return int(args.func(args) or 0)
    except GeofaceError as exc:
        print(f"geoface: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"geoface: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("geoface: terminated" if terminated else "geoface: interrupted", file=sys.stderr)
        return 143 if terminated else 130


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"geoface: warning: {message}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
