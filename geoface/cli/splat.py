"""``geoface splat fit`` — wired into :mod:`geoface.cli` through :func:`register`.

Heavy imports (torch) happen inside the command function.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from geoface.errors import GeofaceError
from geoface._args import SEED, number

__all__ = ["register", "cmd_splat_fit"]


def write_renders(folder, pairs) -> list[Path]:
    """Save held-out (ground truth | fit) pairs side by side as ``heldout_XX.png``."""
    import numpy as np

    from geoface.images import save_image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for k, (gt, fit) in enumerate(pairs):
        gap = np.ones((gt.shape[0], 2, 3))
        p = folder / f"heldout_{k:02d}.png"
        save_image(p, np.concatenate([gt, gap, fit], 1))
        out.append(p)
    return out


def cmd_splat_fit(args) -> int:
    from geoface._io import atomic_path
    from geoface.mesh.io import load_mesh
    from geoface.progress import QUIET, log

    from geoface.splat.fit import FitConfig, fit_mesh, heldout_images
    from geoface.splat.ply import save_ply

    if Path(args.output).suffix.lower() != ".ply":
        raise GeofaceError(f"-o must name a .ply file; got {args.output}")
    mesh = load_mesh(args.mesh)
    if mesh.colors is None:
        raise GeofaceError(f"{args.mesh} has no vertex colours; splat fit needs a mesh with per-vertex "
                           "colours (e.g. `geoface synth head -o head.ply`)")
    cfg = FitConfig(views=args.views, res=args.res, iters=args.iters, sh_degree=args.sh_degree,
                    seed=args.seed, heldout=args.heldout, threads=args.threads,
                    densify=not args.no_densify)
    quiet = getattr(args, "quiet", False) or QUIET
    log(f"fitting {len(mesh.V)} Gaussians to {cfg.views} views of {args.mesh} at {cfg.res}x{cfg.res}, "
        f"{cfg.iters} iterations", quiet=quiet)
    res = fit_mesh(mesh.V, mesh.F, mesh.colors, cfg, progress=None if not quiet else False)
    out = Path(args.output)
    with atomic_path(out) as tmp:  # a temporary name beside OUT, then os.replace
        save_ply(res.gaussians, tmp)
    print(f"{args.mesh} -> {out}: {res.summary()}")
    if args.renders:
        from geoface._io import atomic_dir

        with atomic_dir(args.renders, overwrite=True) as tmp:  # complete or absent
            paths = write_renders(tmp, heldout_images(res, mesh.V, mesh.F, mesh.colors))
        print(f"  held-out ground truth | fit: {len(paths)} PNGs in {args.renders}")
    return 0


def register(sub, common: argparse.ArgumentParser) -> None:
    """Add ``splat fit`` to the ``geoface`` sub-parsers."""
    s = sub.add_parser("splat", help="Gaussian splatting on CPU (needs torch)")
    sd = s.add_subparsers(dest="what", metavar="WHAT")
    sd.required = True
    f = sd.add_parser("fit", parents=[common], help="fit 3D Gaussians to synthetic views of a coloured mesh")
    f.add_argument("mesh", help="mesh with per-vertex colours (e.g. from `geoface synth head -o head.ply`)")
    f.add_argument("-o", "--output", required=True, metavar="OUT.ply", help="3DGS PLY to write")
    f.add_argument("--views", type=number(int, 1, 1000), default=24, help="training views on three orbit rings (24)")
    f.add_argument("--res", type=number(int, 8, 4096), default=128, help="image side in pixels (128)")
    f.add_argument("--iters", type=number(int, 1, 10_000_000), default=1500, help="optimisation steps (1500)")
    f.add_argument("--sh-degree", type=number(int, 0, 3), default=0, help="spherical-harmonics degree 0..3 (0)")
    f.add_argument("--seed", type=SEED, default=0, help='seed of the initialisation and the view order (0)')
    f.add_argument("--heldout", type=number(int, 0, 1000), default=4, help="held-out views for the PSNR report (4)")
    f.add_argument("--threads", type=number(int, 1, 1024), default=None, help="torch CPU threads (default: torch's)")
    f.add_argument("--no-densify", action="store_true", help="no clone/split/prune")
    f.add_argument("--renders", default=None, metavar="DIR", help="write held-out ground truth | fit PNGs here")
    f.set_defaults(func=cmd_splat_fit)
