"""``geoface ddpm train|sample`` — wired into :mod:`geoface.cli` through :func:`register`.

Heavy imports (torch, diffusers) happen inside the command functions.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from geoface.errors import GeofaceError
from geoface._args import SEED, number, renamed

__all__ = ["register", "cmd_ddpm_train", "cmd_ddpm_sample"]


def _device(name):
    """``--device``: cpu or cuda[:k]; cuda only where torch sees a GPU (one line otherwise)."""
    from geoface.nn.config import resolve_device

    return resolve_device(name)


def _quiet(args):
    return True if getattr(args, "quiet", False) else None


def cmd_ddpm_train(args) -> int:
    from geoface.ddpm.model import DDPMConfig, train

    if args.res < 8 or args.steps < 1 or args.batch < 1:
        raise GeofaceError("--res must be >= 8, --steps and --batch >= 1")
    kw = dict(res=args.res, steps=args.steps, batch_size=args.batch, text_encoder=args.text_encoder, seed=args.seed,
              checkpoint_every=args.checkpoint_every, augment=not args.no_augment,
              standardize=not args.no_standardize)
    if args.lr is not None:
        kw["lr"] = args.lr
    cfg = DDPMConfig.preset("tiny" if args.tiny else args.model, **kw)
    out = Path(args.output)
    new_run = not out.exists()
    try:
        last = train(args.data_dir, args.output, cfg, resume=args.resume, device=_device(args.device), quiet=_quiet(args),
                     max_seconds=None if args.max_minutes is None else 60.0 * args.max_minutes,
                     loader_workers=args.loader_workers, cache_mb=args.cache_mb,
                     gradient_checkpointing=args.gradient_checkpointing)
    except BaseException:
        # a run that failed before its first checkpoint (a full disk, bad data, Ctrl-C) leaves no folder behind
        if new_run and out.is_dir() and not out.is_symlink() and not (out / "checkpoint").exists():
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise
    print(f"{Path(args.output) / 'checkpoint'}: step {last['step']}, loss {last['loss']:.4f} "
          + " ".join(f"{k} {v:.4f}" for k, v in last["losses"].items())
          + f" ({last['steps_per_second']:.2f} steps/s)")
    return 0


def cmd_ddpm_sample(args) -> int:
    from geoface.gimage import reconstruct, save_gimage, save_reconstruction

    from geoface.ddpm.model import load_run, sample, to_geometry_images

    if args.n < 1 or args.steps < 1:
        raise GeofaceError("-n and --steps must be >= 1")
    run = load_run(args.run_dir)
    x = sample(run, args.prompt, n=args.n, steps=args.steps, scheduler=args.sampler,
               guidance=args.guidance, seed=args.seed, device=_device(args.device), quiet=_quiet(args))
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    # the pixels every training item covers are covered in every sample (runs that stored them)
    support = run.stats.support if run.stats is not None else None
    from geoface.ddpm.evaluate import mesh_validity

    valid = 0
    gis = to_geometry_images(x, run.state, support)
    for k, gi in enumerate(gis):
        gi.meta["prompt"] = args.prompt
        try:
            mesh = reconstruct(gi)
        except GeofaceError:
            mesh = None  # mesh_validity says why
        # a clean disk: manifold, one component, not folded, not self-intersecting
        v = mesh_validity(gi, mesh=mesh)
        gi.meta["validity"] = {"valid": v.valid, "reason": v.reason, "folded_faces": v.folded_faces,
                               "self_intersecting_faces": v.self_intersecting_faces, "faces": v.faces}
        valid += int(v.valid)
        folder = save_gimage(out / f"sample_{k:03d}", gi)
        msg = f"{folder}"
        if mesh is not None and v.reconstructs:
            save_reconstruction(folder / "reconstruction.obj", mesh, gi)
            msg += f": {len(mesh.V)} vertices, {len(mesh.F)} faces"
        msg += ", a valid surface" if v.valid else f", NOT a valid surface ({v.reason})"
        print(msg)
    line = f"{valid} of {len(gis)} samples are valid surfaces (meta.json: validity)"
    if valid < len(gis):
        step = int(run.state.get("step", 0) or 0)
        line += (f"; the run has trained {step} steps: invalid samples mean too little training for this "
                 "resolution (docs/ddpm.md)" if step else "")
    print(line)
    return 0


def register(sub, common: argparse.ArgumentParser) -> None:
    """Add ``ddpm train`` / ``ddpm sample`` to the ``geoface`` sub-parsers."""
    s = sub.add_parser("ddpm", help="text-guided diffusion on geometry images (needs geoface[learn])")
    sd = s.add_subparsers(dest="what", metavar="WHAT")
    sd.required = True
    t = sd.add_parser("train", parents=[common], help="train or resume a DDPM run on a geometry-image dataset")
    t.add_argument("data_dir", help="dataset folder (manifest.jsonl from `geoface dataset build`, or folders with meta.json)")
    t.add_argument("-o", "--output", required=True, metavar="RUN_DIR",
                   help='folder for the run: checkpoints, config, statistics (new, or resumed with --resume)')
    t.add_argument("--res", type=number(int, 8, 1024), default=64, help="training resolution (divides the image resolution)")
    t.add_argument("--steps", type=number(int, 1, 100_000_000), default=10000, help="total optimisation steps")
    t.add_argument("--batch", type=number(int, 1, 4096), default=8, help="images per step")
    t.add_argument("--model", choices=["small", "base", "tiny"], default="small",
                   help="model size: small (default; 5.9 M parameters, what the README's results use), base "
                        "(paper-sized, for a GPU), tiny (smoke tests)")
    t.add_argument("--lr", type=number(float, 0, 1, lo_open=True), default=None, help="learning rate (default: the preset's)")
    t.add_argument("--max-minutes", type=number(float, 0, 1e7, lo_open=True), default=None,
                   help="stop after this much wall-clock time (a checkpoint is written there)")
    t.add_argument("--loader-workers", type=number(int, 0, 256), default=0,
                   help="processes decoding items in the background (0: the training process)")
    t.add_argument("--cache-mb", type=number(float, 0, 1e7), default=256.0,
                   help="decoded items kept in memory, megabytes (the dataset is read lazily)")
    t.add_argument("--text-encoder", default="minilm", help="minilm | clip:PATH | hash[:DIM]")
    t.add_argument("--checkpoint-every", type=number(int, 1, 100_000_000), default=500, help="steps between checkpoints")
    t.add_argument("--seed", type=SEED, default=0, help="seeds the initial weights, batches and noise")
    t.add_argument("--device", default=None, help="cpu | cuda (default: cuda when available)")
    t.add_argument("--no-augment", action="store_true", help="no random rigid motions of the training heads")
    t.add_argument("--no-standardize", action="store_true",
                   help="denoise the raw dataset-frame channels (the paper's set-up) instead of per-pixel "
                        "standardised ones; samples are then rarely valid meshes")
    t.add_argument("--tiny", action="store_true", help="the same as --model tiny")
    t.add_argument("--gradient-checkpointing", action="store_true",
                   help="recompute activations in the backward pass: less memory, about a third more time per step")
    t.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoint")
    t.set_defaults(func=cmd_ddpm_train)
    p = sd.add_parser("sample", parents=[common], help="sample geometry images + meshes for a prompt")
    p.add_argument("run_dir", metavar="RUN_DIR", help='a run `ddpm train` wrote')
    p.add_argument("prompt", help='what to draw, e.g. "smiling, a wide face" ("" for unconditional)')
    p.add_argument("-n", type=number(int, 1, 10_000), default=4, help="number of samples")
    p.add_argument("--steps", type=number(int, 1, 100_000_000), default=50, help="denoising steps")
    p.add_argument("--sampler", choices=["ddpm", "ddim"], default="ddpm",
                   help="ddpm: stochastic (default; measured to give valid heads where ddim does not, docs/ddpm.md); "
                        "ddim: deterministic")
    renamed(p, "--scheduler", "--sampler")
    p.add_argument("--guidance", type=number(float, 0, 100), default=3.0, help="classifier-free guidance scale")
    p.add_argument("--seed", type=SEED, default=0, help="seeds the noise")
    p.add_argument("--device", default="cpu", help="cpu | cuda")
    p.add_argument("-o", "--output", required=True, metavar="OUT_DIR",
                   help='folder for the samples (geometry images, meshes, previews)')
    p.set_defaults(func=cmd_ddpm_sample)
