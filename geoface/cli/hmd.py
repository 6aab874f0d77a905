"""``geoface hmd synth|train|remove|eval`` — HFM-GS head-mounted-display removal.

Wired into :mod:`geoface.cli` through :func:`register`; torch loads inside the commands.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from geoface.errors import GeofaceError
from geoface.nn.device import train_device
from geoface.progress import args_quiet
from geoface._args import SEED, add_json, json_to_stdout, number, write_json, output_option, synth_landmarks_option

__all__ = ["register"]


def cmd_hmd_synth(args) -> int:
    from geoface.hfm.data import make_synthetic_hmd

    out = Path(args.output)
    if out.exists() and any(out.iterdir()):
        raise GeofaceError(f"{out} exists and is not empty; choose a new folder")
    from geoface._io import atomic_dir
    from geoface.avatar.capture import track_synthetic

    with atomic_dir(out, overwrite=True) as tmp:  # complete or absent: a failure leaves nothing
        if args.head == "ict":
            from geoface.hfm.ict import make_ict_hmd

            reg, use = make_ict_hmd(tmp, frames=args.frames, usage_frames=args.usage_frames, res=args.res,
                                    seed=args.seed, motion=args.motion, jitter=args.jitter, rom=args.rom,
                                    quiet=args_quiet(args))
        else:
            reg, use = make_synthetic_hmd(tmp, frames=args.frames, heldout=args.heldout, res=args.res,
                                          n_vertices=args.vertices, seed=args.seed, motion=args.motion,
                                          quiet=args_quiet(args))
        tracked = track_synthetic((reg, use), args.landmarks, args.head, quiet=args_quiet(args))
        reg, use = out / Path(reg).relative_to(tmp), out / Path(use).relative_to(tmp)
    print(f"{reg}: registration video; {use}: usage video with a headset (+ gt/, hmd_masks/){tracked}")
    return 0


def _add_usage_pose_options(p) -> None:
    """``--poses`` and ``--headset-pose`` of ``hmd remove`` and ``hmd eval``."""
    p.add_argument("--poses", choices=("auto", "file", "track", "landmarks", "image"), default="auto",
                   help="head pose per frame: USAGE_DIR/head_poses.npz (file; a headset's own tracking), that file as "
                        "a head tracker made it, aligned by --pose-align (track; what a VIDEO gets with auto: the "
                        "person's head tracked below the headset), fitted to the landmarks below the headset "
                        "(landmarks), read from the lower-face crop (image), or the first of these the folder allows "
                        "(auto)")
    p.add_argument("--headset-pose", action=argparse.BooleanOptionalAction, default=None,
                   help="with --poses landmarks (or auto without a pose file): also correct the poses by where the "
                        "headset masks (USAGE_DIR/hmd_masks) lie (default: the model's setting)")
    p.add_argument("--pose-align", type=int, default=None, metavar="STEPS",
                   help="with --poses landmarks or track (or auto without a pose file, or on a VIDEO): then turn each frame's pose so that the "
                        "avatar's render matches the pixels outside the headset masks, STEPS gradient steps per frame "
                        "(0: not; default: the model's setting; slow on a CPU, about 0.25 s a step at 128 px)")
    p.add_argument("--pose-align-translation", action=argparse.BooleanOptionalAction, default=None,
                   help="the alignment also moves the head, not only turns it (default: the model's setting)")


def _config(args):
    from geoface.hfm import ABLATIONS, HFMConfig

    kw = dict(iters=args.iters, seed=args.seed, threads=args.threads, vgg_weights=args.vgg_weights,
              densify=not args.no_densify, warmup=args.warmup, ema=args.ema, map_theta=args.map_theta,
              gm_input=args.gm_input, pm_per_component=args.pm_per_component, split_margin=args.split_margin)
    for arg, field in (("y_split", "y_split"), ("pose_landmarks", "registration_landmarks"),
                       ("pose_residual", "pose_residual"), ("pose_head_detach", "image_pose_detach"),
                       ("usage_landmarks", "usage_landmarks"), ("calibration_weights", "pose_calibration_weighted"),
                       ("calibration_expressions", "pose_calibration_expressions"), ("pose_refine", "pose_refine")):
        if getattr(args, arg) is not None:  # None: the model's default
            kw[field] = getattr(args, arg)
    kw.update(ABLATIONS[args.ablation])
    return HFMConfig(**kw)


def cmd_hmd_train(args) -> int:
    from geoface.progress import log

    from geoface.hfm import train_hfm

    from geoface._io import output_folder

    out = Path(args.output)
    cfg = _config(args)
    with output_folder(out, args.force) as tmp:  # complete or absent; never into a user's files
        info = train_hfm(args.reg_dir, tmp, cfg, progress=None if not args_quiet(args) else False, log=log,
                         poses=args.poses, device=train_device(args))
    h = info["history"]
    first = sum(r["loss"] for r in h[:20]) / len(h[:20])
    last = sum(r["loss"] for r in h[-20:]) / len(h[-20:])
    print(f"{args.reg_dir} -> {out}: {cfg.iters} steps in {info['seconds']:.1f} s, loss {first:.4f} -> {last:.4f}, "
          f"{info['n_gaussians']} Gaussians ({info['n_upper']} upper), {info['dropped_children']} split children "
          f"dropped at the boundary; weights averaged over the last {info['averaged_steps']} steps; head poses "
          + ("from head_poses.npz" if info["poses"] == "file" else
             f"fitted to {info['pose_landmarks']} landmarks (median {info['pose_fit_rms_px']} px)")
          + (f"; usage poses from the lower landmarks calibrated to them ({info['pose_calibration']} components)"
             if info.get("pose_calibration") else ""))
    return 0


def _load_for_usage(args):
    """The model of ``args.model_dir`` with the usage pose options (``--headset-pose``,
    ``--pose-align``, ``--pose-align-translation``) applied where given."""
    from geoface.hfm import HFMConfig, load_hfm

    if args.pose_align is not None and args.pose_align < 0:
        raise GeofaceError(f"--pose-align: a number of steps per frame, >= 0; got {args.pose_align}")
    model = load_hfm(args.model_dir)
    given = {f: getattr(args, f) for f in ("headset_pose", "pose_align", "pose_align_translation")
             if getattr(args, f) is not None}
    model.cfg = HFMConfig(**{**model.cfg.to_dict(), **given}) if given else model.cfg
    return model


def cmd_hmd_remove(args) -> int:
    if args.output is None and args.video is None:
        raise GeofaceError("say where the frames go: -o OUT_DIR (PNG frames) and/or --video OUT.mp4")
    if args.video is not None and Path(args.video).suffix.lower() != ".mp4":
        raise GeofaceError(f"--video: an .mp4 path; got {args.video}")
    model = _load_for_usage(args)
    src = Path(args.usage_dir)
    if not src.exists():
        raise GeofaceError(f"{src}: no such video or usage folder")
    if not src.is_file():
        return _remove_folder(args, model, src, str(src))
    # a headset video: captured first (face crops, landmarks below the headset, head track, the
    # headset segmented from the pixels) into a temporary usage folder
    import tempfile

    from geoface._io import check_input
    from geoface.avatar.clip import capture_clip
    from geoface.avatar.protocol import usage_from_capture

    check_input(src)
    quiet = args_quiet(args)
    res = args.res or (model.registration_size or (512, 512))[0]
    ident = getattr(model, "ict_identity", None)  # registered on a capture: its head, tracked below the headset
    with tempfile.TemporaryDirectory(prefix="geoface_hmd_") as td:
        capture_clip(src, Path(td) / "capture", res=res, overlay=False, identity=ident, headset=ident is not None,
                     refine=ident is not None, quiet=quiet)
        usage = usage_from_capture(Path(td) / "capture", Path(td) / "usage", quiet=quiet)
        poses = "track" if ident is not None and args.poses == "auto" else args.poses
        return _remove_folder(args, model, usage, str(src), poses)


def _remove_folder(args, model, usage_dir: Path, shown_as: str, poses: str | None = None) -> int:
    from geoface.hfm import remove_hmd
    from geoface.hfm.data import load_video

    video = load_video(usage_dir)
    out = None if args.output is None else Path(args.output)
    composite = not args.no_composite
    from geoface._io import output_folder

    with output_folder(out, args.force) as tmp:  # the frames appear all at once, or not at all
        renders, times, source = remove_hmd(model, video, out_dir=tmp, composite=composite, poses=poses or args.poses,
                                            with_source=True)
    import numpy as np

    where = [] if out is None else [f"{out}/frames"]
    if args.video is not None:
        from geoface.video import write_video

        if composite and video.hmd_masks is not None:
            frames = (np.where(video.hmd_masks[t][..., None], renders[t], video.frames[t]) for t in range(len(renders)))
        else:
            frames = iter(renders)
        wav = usage_dir / "audio.wav"
        import json

        meta = json.loads((usage_dir / "meta.json").read_text(encoding="utf-8"))
        write_video(frames, args.video, fps=args.fps or float(meta.get("fps", 25.0)),
                    audio=wav if wav.is_file() else None)
        where.append(str(args.video))
    med = float(np.median(times))
    print(f"{shown_as} -> {' and '.join(where)}: {len(times)} frames, {1 / med:.1f} FPS "
          f"(median {1000 * med:.1f} ms per frame: crop, encode, deform, render); head poses: {source}")
    return 0


def cmd_hmd_eval(args) -> int:
    import numpy as np

    from geoface.hfm import evaluate_hmd

    model = _load_for_usage(args)
    from geoface.hfm.data import load_video

    res = evaluate_hmd(model, load_video(args.usage_dir), poses=args.poses)
    say = (lambda *a, **k: None) if json_to_stdout(args) else print
    say(f"{args.usage_dir} (head poses: {res['poses']}): face PSNR {res['psnr_face']:.2f} dB SSIM {res['ssim_face']:.4f}; occluded region "
          f"PSNR {res['psnr_occluded']:.2f} dB SSIM {res['ssim_occluded']:.4f}; {res['fps']:.1f} FPS "
          f"({res['frames']} frames); expression motion upper {res['upper_motion_mm']:.2f} mm, "
          f"lower {res['lower_motion_mm']:.2f} mm")
    if not np.isnan(res["psnr_occluded_outline"]):
        say(f"occluded region: interior PSNR {res['psnr_occluded_interior']:.2f} dB, outline (the face's edge under the "
            f"headset) {res['psnr_occluded_outline']:.2f} dB")
    if res.get("expression_frames") == 0:
        say("expression region: no usage frame has an upper-face expression to score")
    elif "psnr_expression" in res:
        say(f"expression region (what brows and lids change, {res['expression_frames']} frames): PSNR "
              f"{res['psnr_expression']:.2f} dB SSIM {res['ssim_expression']:.4f}; the rest-pose upper face "
              f"scores {res['psnr_expression_rest']:.2f} dB there")
    if args.baselines is not None:
        res["baselines"] = _baselines(model, args)
        for name, r in res["baselines"].items():
            say(f"  {name:<28} occluded PSNR {r['psnr_occluded']:.2f} dB SSIM {r['ssim_occluded']:.4f}; person "
                f"PSNR {r['psnr_person']:.2f} dB")
    write_json(args, res)
    return 0


def _baselines(model, args) -> dict:
    """``hmd eval --baselines REG_DIR``: the avatar and the trivial baselines scored alike on the
    usage folder's frames (:mod:`geoface.avatar.protocol`: the headset's pixels restored)."""
    import numpy as np

    from geoface.avatar import protocol as P
    from geoface.capture import Capture
    from geoface.hfm import remove_hmd
    from geoface.hfm.data import load_video

    te = Capture(args.usage_dir)
    gt = te.images("gt", rgb=True)
    if gt is None or not te.has(P.TRUTH):
        raise GeofaceError(f"{args.usage_dir}: --baselines scores a test folder of `geoface hmd holdout` (gt/, truth/)")
    regs = P.regions(args.usage_dir)
    shown = te.frames()
    hmd = regs["occluded"][..., None]
    R, _ = remove_hmd(model, load_video(args.usage_dir), poses=args.poses)
    nf, _ = P.nearest_frame(args.baselines, args.usage_dir)
    preds = {"avatar": R, "nearest training frame": nf, "mean training face": P.mean_face(args.baselines, len(gt))}
    out = {}
    for name, pred in preds.items():
        sc = P.score_regions(np.where(hmd, pred, shown), gt, regs)
        out[name] = {k: sc[k] for k in ("psnr_occluded", "ssim_occluded", "psnr_person", "ssim_person")}
    return out


def cmd_hmd_holdout(args) -> int:
    from geoface.avatar.protocol import split_capture

    sp = split_capture(args.capture, args.output, test=args.test, overwrite=args.force, quiet=args_quiet(args))
    print(f"{args.capture} -> {sp.train} ({sp.n_train} frames: register with `hmd train`) and {sp.test} ({sp.n_test} "
          f"frames, a headset drawn over them at the tracked pose: `hmd remove`, `hmd eval --baselines {sp.train}`)")
    return 0


def register(sub, common: argparse.ArgumentParser) -> None:
    """Add ``geoface hmd ...`` to the ``geoface`` sub-parsers."""
    h = sub.add_parser("hmd", help="HFM-GS: remove a head-mounted display from video (needs torch)")
    hs = h.add_subparsers(dest="what", metavar="WHAT")
    hs.required = True
    s = hs.add_parser("synth", parents=[common], help="write synthetic registration and usage videos")
    output_option(s, "OUT_DIR", "folder for the registration and usage captures")
    s.add_argument("--frames", type=number(int, 2, 100_000), default=200, help="frames in the whole sequence (200)")
    s.add_argument("--heldout", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.2, help="last fraction that becomes the usage video (0.2)")
    s.add_argument("--res", type=number(int, 16, 4096), default=128, help="image side in pixels (128)")
    s.add_argument("--head", choices=("procedural", "ict"), default="procedural",
                   help="procedural (the toy head; the sequence is split) or ict (an ICT-FaceKit person, lit, talking; "
                        "--seed picks the person)")
    s.add_argument("--usage-frames", type=number(int, 1, 100_000), default=None,
                   help="--head ict: frames of the usage video, its own sequence (default frames/4)")
    s.add_argument("--vertices", type=number(int, 1000, 200_000), default=8000, help="procedural head vertices (8000)")
    s.add_argument("--motion", type=number(float, 0, 100), default=1.0, help="head motion scale (1; 0 = still)")
    s.add_argument("--jitter", type=number(float, 0, 100), default=1.0, help="--head ict: camera shake scale (1)")
    s.add_argument("--rom", type=number(float, 0, 3600), default=0.0, metavar="SECONDS",
                   help="--head ict: the registration video opens with a range of motion of this length: surprise, "
                        "smile and anger in turn at full weight (0: none)")
    synth_landmarks_option(s)
    s.add_argument("--seed", type=SEED, default=0, help='seed of the head, the motion and the expressions (0)')
    s.set_defaults(func=cmd_hmd_synth)
    from geoface.hfm.config import HFMConfig

    base = HFMConfig()
    on_off = {True: "on", False: "off"}
    t = hs.add_parser("train", parents=[common], help="register a person from an unoccluded video folder")
    t.add_argument("reg_dir", metavar="REG_DIR",
                   help="a registration folder: `hmd synth`'s registration/, `hmd holdout`'s train/, or a capture")
    t.add_argument("-o", "--output", required=True, metavar="MODEL_DIR", help="folder for the trained model (new)")
    t.add_argument("--iters", type=number(int, 1, 10_000_000), default=2000, help="optimisation steps (2000)")
    t.add_argument("--warmup", type=number(float, 0, 1, hi_open=True), default=0.2,
                   help="fraction of the steps that trains the Gaussians alone before the networks (0.2)")
    t.add_argument("--ema", type=number(float, 0, 1, hi_open=True), default=0.99, metavar="DECAY",
                   help="save the moving average of the weights over the steps after density control, with this "
                        "decay per step (0.99; 0 saves the last step's weights)")
    t.add_argument("--vgg-weights", default=None, metavar="FILE",
                   help="local VGG-16 feature weights (.safetensors or .pth) for the perceptual term (default: none, "
                        "the term is left out)")
    t.add_argument("--y-split", type=number(float), default=None, help="upper/lower split height y_t (default: meta.json)")
    t.add_argument("--threads", type=number(int, 1, 1024), default=None, help="torch CPU threads (default: torch's)")
    t.add_argument("--poses", choices=("auto", "file", "landmarks"), default="auto",
                   help="registration head poses: head_poses.npz (file), fitted to the landmarks (landmarks), "
                        "or the file when there is one (auto)")
    t.add_argument("--device", default=None, help="cpu or cuda (default: cuda when torch sees a GPU)")
    t.add_argument("--seed", type=SEED, default=0, help="seed of the initialisation and the frame order (0)")
    x = t.add_argument_group("experiments", "research knobs for ablations (docs/hmd.md); the defaults are the "
                                            "settings measured there")
    x.add_argument("--ablation", choices=sorted(ABLATION_NAMES), default="full",
                   help="switch off one element of the paper (full: none off)")
    x.add_argument("--no-densify", action="store_true", help="no clone/split/prune")
    x.add_argument("--map-theta", action="store_true", help="MLP_mapping also reads the latent θ (the paper's input)")
    x.add_argument("--gm-input", choices=("x", "xsr"), default="x",
                   help="MLP_gm embeds the position (x) or position, scale and rotation (xsr, the paper's)")
    x.add_argument("--pm-per-component", action="store_true",
                   help="one MLP_pm per deformation component (ΔX, ΔS, ΔR), each mapping head reads its own")
    x.add_argument("--split-margin", type=number(float, 0, 1), default=0.0, metavar="D",
                   help="margin d (metres) of the boundary losses: each half held d from y_t (0)")
    x.add_argument("--pose-landmarks", choices=("rigid", "stable", "lower"), default=base.registration_landmarks,
                   help="registration poses fitted to the landmarks that move little with expressions (rigid), "
                        "to those of them that stay put best (stable: jaw line ends, nose ridge and tip, eye corners), "
                        f"or to those below a headset, as the usage poses are (lower) ({base.registration_landmarks})")
    x.add_argument("--usage-landmarks", choices=("lower", "stable"), default=base.usage_landmarks,
                   help="the landmarks below a headset that usage poses are fitted to (and the calibration learns): "
                        f"the 12 rigid ones (lower) or the 8 of them that stay put best (stable) ({base.usage_landmarks})")
    x.add_argument("--pose-residual", action=argparse.BooleanOptionalAction, default=base.pose_residual,
                   help=f"the global pose MLP corrects the tracked head pose of each frame "
                        f"(default: {on_off[base.pose_residual]})")
    x.add_argument("--pose-head-detach", action=argparse.BooleanOptionalAction, default=base.image_pose_detach,
                   help="the pose MLP that reads the head pose from the crop learns alone: its loss does not train "
                        f"the image encoder (default: {on_off[base.image_pose_detach]})")
    x.add_argument("--calibration-weights", action=argparse.BooleanOptionalAction,
                   default=base.pose_calibration_weighted,
                   help="the usage pose calibration weighs each lower landmark by how little it moved in "
                        f"registration (default: {on_off[base.pose_calibration_weighted]})")
    x.add_argument("--calibration-expressions", type=number(int, 0, 10_000), default=base.pose_calibration_expressions,
                   metavar="N",
                   help="the usage pose calibration also sees each registration frame N times with generic "
                        f"expressions of the ICT-FaceKit model added to its landmarks "
                        f"(default: {base.pose_calibration_expressions}, off)")
    x.add_argument("--pose-refine", action=argparse.BooleanOptionalAction, default=base.pose_refine,
                   help="registration poses fitted to the landmarks are corrected frame by frame with the "
                        f"image loss (default: {on_off[base.pose_refine]})")
    t.set_defaults(func=cmd_hmd_train)
    o = hs.add_parser("holdout", parents=[common],
                      help="a real clip's capture split by time: the first frames register, the last ones get a "
                           "headset drawn over them to test (as the papers score real video)")
    o.add_argument("capture", metavar="CAPTURE_DIR", help="a folder `geoface capture` wrote")
    o.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="folder for train/ and test/")
    o.add_argument("--test", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.2,
                   help="the last fraction of the frames that tests (0.2)")
    o.set_defaults(func=cmd_hmd_holdout)
    r = hs.add_parser("remove", parents=[common], help="restore the full face in a headset video (streams, reports FPS)")
    r.add_argument("model_dir", metavar="MODEL_DIR", help='a model `hmd train` wrote')
    r.add_argument("usage_dir", metavar="USAGE_DIR|VIDEO",
                   help="a usage folder, or a headset video (captured first: face crops, the landmarks below the "
                        "headset, the head track, the headset segmented from the pixels by its colour where the face mesh puts the eyes)")
    r.add_argument("-o", "--output", default=None, metavar="OUT_DIR", help="write the frames as OUT_DIR/frames/*.png")
    r.add_argument("--video", default=None, metavar="OUT.mp4", help="write an H.264 MP4 (with the sound, if any)")
    r.add_argument("--res", type=number(int, 16, 4096), default=None,
                   help="VIDEO: the crops' side in pixels (default: the registration frames')")
    r.add_argument("--fps", type=number(float, 0.1, 240), default=None,
                   help="frame rate of the video (default: the usage folder's, else 25)")
    _add_usage_pose_options(r)
    r.add_argument("--no-composite", action="store_true", help="write the avatar renders, not frames with the HMD region replaced")
    r.set_defaults(func=cmd_hmd_remove)
    from geoface.cli.export import add_export_parser

    add_export_parser(hs, common, "the registered avatar's", "a usage folder (its frames drive the avatar)", True)
    e = hs.add_parser("eval", parents=[common], help="PSNR/SSIM (whole face, occluded region) and FPS on a usage folder with gt/")
    e.add_argument("model_dir", metavar="MODEL_DIR", help='a model `hmd train` wrote')
    e.add_argument("usage_dir", metavar="USAGE_DIR",
                   help="a usage folder with the truth under the headset (gt/): `hmd synth`'s usage/ or `hmd holdout`'s test/")
    _add_usage_pose_options(e)
    e.add_argument("--baselines", default=None, metavar="REG_DIR",
                   help="also score the trivial baselines on the same frames (the nearest frame of REG_DIR, warped "
                        "by the tracked pose; the mean frame of REG_DIR): USAGE_DIR from `hmd holdout`")
    add_json(e, "the figures")
    e.set_defaults(func=cmd_hmd_eval)


# the keys of geoface.hfm.ABLATIONS (kept here so that building the parser imports no torch)
ABLATION_NAMES = ("full", "no_global_pose", "no_gaussian_feature_mapping", "no_gaussian_feature_mapping_separate",
                  "no_feature_mapping", "no_sampling")
