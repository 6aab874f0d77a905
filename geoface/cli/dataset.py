"""``geoface dataset build | ict``."""
from __future__ import annotations

from pathlib import Path

from .._args import number, renamed
from ._common import guard_outputs, axis

def dataset_options(b) -> None:
    """The conversion and scheduling flags that ``dataset build`` and ``dataset ict`` share."""
    b.add_argument("--res", type=number(int, 4, 8192), default=512, help="image resolution N (default 512)")
    b.add_argument("--augment", type=number(int, 1, 8), default=8, help="corner sets per mesh, 1..8 (default 8)")
    b.add_argument("--workers", type=number(int, 1, 1024), default=None, help="local worker processes (default: the number of cores; 1 = serial)")
    b.add_argument("--dask", default=None, metavar="ADDRESS", help="a Dask scheduler's address (tcp://host:port): "
                   "run on that cluster instead of the local pool")
    renamed(b, "--scheduler", "--dask")
    b.add_argument("--lam", type=number(float, 0, 1000, lo_open=True), default=2.5, help="mass factor on the ROI (2.5)")
    b.add_argument("--blend", type=number(float, 0, 1, hi_open=True), default=0.1,
                   help="share of the conformal map's area in OT's target measure (0.1; 0 = the paper's measure)")
    b.add_argument("--feature", type=number(float, 0, 100), default=4.0,
                   help="extra mass on sharp spots: their masses times 1 + FEATURE (4, as convert; 0 = the paper's measure)")
    b.add_argument("--method", choices=["ot", "conformal"], default="ot", help="measure-preserving (ot) or conformal")
    b.add_argument("--ot-tol", type=number(float, 0, 1, lo_open=True, hi_open=True), default=1e-3,
                   help="OT tolerance: max relative cell-area error (1e-3)")
    b.add_argument("--reconstruct", action="store_true", help="also write reconstruction.obj and its error")
    b.add_argument("--retry-failed", action="store_true", help="try items that failed in an earlier run again")
    b.add_argument("--strict", action="store_true", help="exit code 1 when any item failed")
    b.add_argument("--up", default="auto", type=axis(), help="up axis (default auto: from the shape, any axis convention)")
    b.add_argument("--open", choices=["auto", "plane", "cap", "none"], default="auto", help="how to open a closed surface")
    b.add_argument("--no-find-face", dest="find_face", action="store_false",
                   help="with --up auto, do not look for each mesh's face (the shape's cues alone; about 2 s less a mesh)")


def _dataset_report(args, out: Path, s: dict) -> int:
    print(f"{out}/: {s['done']} items built, {s['failed']} failed, {s['skipped']} skipped "
          f"({s['seconds']:.1f} s, {s['items_per_minute']:.1f} items/min); manifest {out / 'manifest.jsonl'}")
    for item, err in s["failures"].items():
        print(f"  failed {item}: {err}")
    return 1 if (args.strict and s["failed"]) else 0


def _dataset_opts(args):
    from ..dataset import DatasetOptions

    return DatasetOptions(res=args.res, augment=args.augment, roi=args.roi, lam=args.lam, blend=args.blend, feature=args.feature, method=args.method,
                          ot_tol=args.ot_tol, reconstruct=args.reconstruct, up=args.up, open=args.open,
                          find_face=args.find_face)


def cmd_dataset_build(args) -> int:
    from ..dataset import build_dataset

    out, inp = Path(args.output), Path(args.in_dir)
    # an existing dataset folder is resumed (its manifest records the options it was built with)
    guard_outputs(args, [inp, args.labels], [out], resumable=[out] if (out / "manifest.jsonl").is_file() else [])
    s = build_dataset(inp, out, _dataset_opts(args), workers=args.workers, scheduler=args.dask, labels=args.labels,
                      retry_failed=args.retry_failed, rebuild=args.force)
    return _dataset_report(args, out, s)


def cmd_dataset_ict(args) -> int:
    from ..dataset import build_ict_dataset

    out = Path(args.output)
    guard_outputs(args, [args.model], [out], resumable=[out] if (out / "manifest.jsonl").is_file() else [])
    s = build_ict_dataset(out, args.count, _dataset_opts(args), seed=args.seed, model=args.model, mix_share=args.mix_share,
                          heldout_share=args.heldout_share, workers=args.workers, scheduler=args.dask,
                          retry_failed=args.retry_failed, rebuild=args.force)
    return _dataset_report(args, out, s)


def register(sub, common) -> None:
    """``geoface dataset build|ict``."""
    from .._args import SEED, number, output_option
    from ._common import verbs

    s = sub.add_parser("dataset", help="build geometry-image datasets from folders of meshes")
    dv = verbs(s, common)
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
