"""``geoface talk synth|train|animate|eval`` — THGS talking avatars.

Wired into :mod:`geoface.cli` through :func:`register`; torch loads inside the commands.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from geoface.errors import GeofaceError

__all__ = ["register"]

from geoface.nn.device import train_device  # noqa: E402  (argparse only, no torch)
from geoface.progress import args_quiet  # noqa: E402
from geoface._io import output_folder  # noqa: E402
from geoface._args import SEED, add_json, json_to_stdout, number, write_json, output_option, synth_landmarks_option

#: THGSConfig.lambda_landmarks's default (kept here so that building the parser imports no torch)
THGS_LANDMARK_WEIGHT = 3.0
#: THGSConfig.audio_window's default (likewise)
THGS_AUDIO_WINDOW = 2
#: THGSConfig.lr_pose's and pose_decay's defaults (likewise)
THGS_LR_POSE, THGS_POSE_DECAY = 1e-2, 10.0


def cmd_talk_synth(args) -> int:
    from geoface.thgs.data import make_synthetic_talking

    perturb = (0.0, 0.0)
    if args.perturb is not None:
        try:
            perturb = tuple(float(x) for x in args.perturb.split(","))
        except ValueError:
            perturb = ()
        if len(perturb) != 2 or not all(0 <= x < 90 for x in perturb):
            raise GeofaceError(f"--perturb: degrees,millimetres like 3,5 (each in [0, 90)); got {args.perturb!r}")
        if args.head != "ict":
            raise GeofaceError("--perturb needs --head ict (its captures keep the true poses beside the tracked ones)")
    out = Path(args.output)
    if out.exists() and any(out.iterdir()):
        raise GeofaceError(f"{out} exists and is not empty; choose a new folder")
    from geoface._io import atomic_dir
    from geoface.avatar.capture import track_synthetic

    with atomic_dir(out, overwrite=True) as tmp:  # complete or absent: a failure leaves nothing
        if args.head == "ict":
            from geoface.thgs.ict import make_ict_talking

            make_ict_talking(tmp, seconds=args.seconds, fps=args.fps, res=args.res, n_vertices=args.vertices,
                             seed=args.seed, perturb=perturb, quiet=args_quiet(args))
        else:
            make_synthetic_talking(tmp, seconds=args.seconds, fps=args.fps, res=args.res, n_vertices=args.vertices,
                                   seed=args.seed, quiet=args_quiet(args))
        tracked = track_synthetic((tmp,), args.landmarks, args.head, quiet=args_quiet(args))
        if (tmp / "landmarks_true.json").is_file() and not any(perturb):  # tracked: the head poses too, from them
            from geoface.thgs.data import fit_head_poses

            fit = fit_head_poses(tmp)
            tracked += f"; head poses fitted to them ({fit['rms_px']:.2f} px median), the capture's kept as poses_true.npz"
    what = "ICT-FaceKit person" if args.head == "ict" else "synthetic talking head"
    extra = f", tracking off by {perturb[0]:g}° / {perturb[1]:g} mm per frame" if any(perturb) else ""
    print(f"{out}: {what}, {args.seconds:g} s at {args.fps:g} fps, {args.res}² (audio.wav, poses.npz){extra}{tracked}")
    return 0


def cmd_talk_train(args) -> int:
    from geoface.thgs.model import THGSConfig
    from geoface.thgs.train import train_thgs

    out = Path(args.output)
    cfg = THGSConfig(iters=args.iters, stage_scale=args.stage_scale, use_leb=not args.no_leb,
                     use_saam=not args.no_saam, use_audio_pose=not args.no_audio_pose,
                     lambda_landmarks=args.landmark_weight, heldout=args.heldout, seed=args.seed, threads=args.threads,
                     audio_window=args.audio_window, lr_pose=args.lr_pose, pose_decay=args.pose_decay,
                     artic_prefit=args.prefit)
    with output_folder(out, args.force) as tmp:  # complete or absent; never into a user's files
        info = train_thgs(args.data_dir, tmp, cfg, progress=None if not args_quiet(args) else False,
                          device=train_device(args))
    h = info["history"]
    first = sum(r["loss"] for r in h[:20]) / len(h[:20])
    last = sum(r["loss"] for r in h[-20:]) / len(h[-20:])
    print(f"{args.data_dir} -> {out}: {cfg.iters} steps in {info['seconds']:.1f} s, loss {first:.4f} -> {last:.4f}, "
          f"{info['n_gaussians']} Gaussians; stages start at {list(info['stages'])}")
    return 0


def cmd_talk_animate(args) -> int:
    from geoface.thgs.inference import animate, load_thgs

    if args.output is None and args.video is None:
        raise GeofaceError("say where the animation goes: -o OUT_DIR (PNG frames) and/or --video OUT.mp4")
    if args.video is not None and Path(args.video).suffix.lower() != ".mp4":
        raise GeofaceError(f"--video: an .mp4 path; got {args.video}")
    model = load_thgs(args.model_dir)
    out = None if args.output is None else Path(args.output)
    import tempfile

    from geoface.track.frames import VIDEO_SUFFIXES

    with tempfile.TemporaryDirectory(prefix="geoface_talk_") as td:
        audio = Path(args.audio)
        if audio.suffix.lower() in VIDEO_SUFFIXES:  # a video: its sound drives the avatar
            from geoface._io import check_input
            from geoface.avatar.clip import extract_audio

            check_input(audio)
            if not extract_audio(audio, Path(td) / "audio.wav"):
                raise GeofaceError(f"{audio}: the video has no sound to drive the avatar")
            audio = Path(td) / "audio.wav"
        with output_folder(out, args.force) as tmp:  # the frames appear all at once, or not at all
            frames, times = animate(model, audio, tmp, poses=args.poses, fps=args.fps)
        return _animated(args, out, frames, times, audio)


def _animated(args, out, frames, times, audio: Path) -> int:
    import numpy as np

    where = [] if out is None else [f"{out}/frames"]
    if args.video is not None:
        from geoface.video import write_video

        wav = audio if audio.suffix.lower() == ".wav" else None
        write_video(frames, args.video, fps=args.fps, audio=wav)
        where.append(f"{args.video}" + (" (with the audio)" if wav else ""))
    print(f"{args.audio} -> {' and '.join(where)}: {len(frames)} frames, rendered at {1 / float(np.median(times)):.1f} FPS "
          f"(median; mean {len(times) / max(float(times.sum()), 1e-9):.1f})")
    return 0


def cmd_talk_eval(args) -> int:
    from geoface.thgs.inference import load_thgs
    from geoface.thgs.eval import evaluate_thgs
    from geoface.thgs.data import load_talking

    res = evaluate_thgs(load_thgs(args.model_dir), load_talking(args.data_dir), args.heldout)
    say = (lambda *a, **k: None) if json_to_stdout(args) else print
    say(f"{args.data_dir}: held-out PSNR {res['psnr']:.2f} dB SSIM {res['ssim']:.4f}, mouth PSNR "
          f"{res['psnr_mouth']:.2f} dB; lip sync r = {res['lipsync_corr']:.2f} (real frames {res['lipsync_corr_real']:.2f}); "
          f"{res['fps']:.1f} FPS ({res['frames']} frames)")
    if "pose_before" in res:
        b, a = res["pose_before"], res["pose_after"]
        say(f"head pose of the training frames against the truth: {b['rot_deg_mean']:.2f}° / {b['mm_mean']:.1f} mm "
            f"tracked, {a['rot_deg_mean']:.2f}° / {a['mm_mean']:.1f} mm corrected (means)")
    write_json(args, res)
    return 0


def register(sub, common: argparse.ArgumentParser) -> None:
    """Add ``geoface talk ...`` to the ``geoface`` sub-parsers."""
    h = sub.add_parser("talk", help="THGS talking avatars (needs torch)")
    hs = h.add_subparsers(dest="what", metavar="WHAT")
    hs.required = True
    s = hs.add_parser("synth", parents=[common], help="write a synthetic talking-head data folder")
    output_option(s, "OUT_DIR", "folder for the talking-head capture")
    s.add_argument("--seconds", type=number(float, 0, 3600, lo_open=True), default=8.0,
                   help='length of the clip in seconds (8)')
    s.add_argument("--fps", type=number(float, 0.1, 240), default=25.0, help='frames per second (25)')
    s.add_argument("--res", type=number(int, 16, 4096), default=128, help='frame side in pixels (128)')
    s.add_argument("--vertices", type=number(int, 1000, 200_000), default=6000, help="template vertices (Gaussians)")
    s.add_argument("--head", choices=("procedural", "ict"), default="procedural",
                   help="procedural head, or an ICT-FaceKit person (lit skin, eyes, teeth; ARKit blendshapes)")
    s.add_argument("--perturb", default=None, metavar="DEG,MM",
                   help="ict: each frame's tracked head pose off by DEG degrees and MM millimetres (true poses kept)")
    synth_landmarks_option(s)
    s.add_argument("--seed", type=SEED, default=0, help='seed of the person, the speech and the motion (0)')
    s.set_defaults(func=cmd_talk_synth)
    t = hs.add_parser("train", parents=[common], help="fit a talking avatar to a data folder")
    t.add_argument("data_dir", metavar="DATA_DIR",
                   help="a capture: `talk synth`'s folder or one `geoface capture` wrote")
    t.add_argument("-o", "--output", required=True, metavar="MODEL_DIR", help='folder for the trained model (new)')
    t.add_argument("--iters", type=number(int, 1, 10_000_000), default=3000, help='optimisation steps (3000)')
    t.add_argument("--stage-scale", type=number(float, 0, 100, lo_open=True), default=None,
                   help="factor on the paper's stage starts 1.5K/15K/25K/50K of 150K (default iters/150000: the paper's fractions of the run)")
    t.add_argument("--no-leb", action="store_true", help="ablation: no learnable expression blendshapes")
    t.add_argument("--no-saam", action="store_true", help="ablation: no spatial audio attention")
    t.add_argument("--no-audio-pose", action="store_true",
                   help="ablation: the DOFs the tracker does not measure (jaw, mouth) stay at rest instead of following the audio")
    t.add_argument("--prefit", action="store_true",
                   help="fit the audio articulation to the mouth landmarks of all training frames when it switches on")
    t.add_argument("--landmark-weight", type=number(float, 0, 1e6), default=THGS_LANDMARK_WEIGHT, metavar="W",
                   help=f"weight of the mouth landmarks of DATA_DIR/landmarks.json, when it has one "
                        f"({THGS_LANDMARK_WEIGHT}; 0: not used)")
    t.add_argument("--audio-window", type=number(int, 0, 100), default=THGS_AUDIO_WINDOW, metavar="N",
                   help="the audio modules also read the features of N frames before and after each frame "
                        f"({THGS_AUDIO_WINDOW})")
    t.add_argument("--lr-pose", type=number(float, 0, 1, lo_open=True), default=THGS_LR_POSE, metavar="RAD",
                   help=f"step of the per-frame pose corrections, radians at a typical misfit ({THGS_LR_POSE:g})")
    t.add_argument("--pose-decay", type=number(float, 1, 1e6), default=THGS_POSE_DECAY, metavar="F",
                   help=f"the corrections' step falls F times by the last training step ({THGS_POSE_DECAY:g})")
    t.add_argument("--heldout", type=number(float, 0, 1, lo_open=True, hi_open=True), default=0.2, help="last fraction of frames kept out of training (0.2)")
    t.add_argument("--threads", type=number(int, 1, 1024), default=None, help="torch CPU threads (default: torch's)")
    t.add_argument("--seed", type=SEED, default=0, help='seed of the initialisation and the frame order (0)')
    t.add_argument("--device", default=None, help="cpu or cuda (default: cuda when torch sees a GPU)")
    t.set_defaults(func=cmd_talk_train)
    a = hs.add_parser("animate", parents=[common], help="drive a trained avatar by speech (frames, FPS)")
    a.add_argument("model_dir", metavar="MODEL_DIR", help='a model `talk train` wrote')
    a.add_argument("--audio", required=True, help="the speech: a WAV, a video (its sound), or .npy/.npz per-frame features")
    a.add_argument("--poses", default=None, help=".npz with rot [T, J, 3], transl [T, 3], expr [T, K]")
    a.add_argument("--fps", type=number(float, 0.1, 240), default=25.0,
                   help='frames per second of the animation (25)')
    a.add_argument("-o", "--output", default=None, metavar="OUT_DIR", help="write the frames as OUT_DIR/frames/*.png")
    a.add_argument("--video", default=None, metavar="OUT.mp4",
                   help="write an H.264 MP4 at --fps, with the speech when --audio is a WAV")
    a.set_defaults(func=cmd_talk_animate)
    from geoface.cli.export import add_export_parser

    add_export_parser(hs, common, "the talking avatar's",
                      "a WAV (rest pose) or a `talk synth` folder (its poses); default: the rest pose, silent", False)
    e = hs.add_parser("eval", parents=[common], help="held-out PSNR/SSIM, mouth error, lip sync, FPS")
    e.add_argument("model_dir", metavar="MODEL_DIR", help='a model `talk train` wrote')
    e.add_argument("data_dir", metavar="DATA_DIR",
                   help='the capture it was trained on (its held-out frames are scored)')
    e.add_argument("--heldout", type=number(float, 0, 1, lo_open=True, hi_open=True), default=None, help="default: the fraction used in training")
    add_json(e, "the figures")
    e.set_defaults(func=cmd_talk_eval)
