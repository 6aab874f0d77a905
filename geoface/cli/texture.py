"""``geoface texture synth|train|reconstruct`` — wired into :mod:`geoface.cli` through :func:`register`.

Heavy imports (torch) happen inside the command functions.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError
from geoface._args import SEED, number, output_option
from geoface.images import save_image

__all__ = ["register"]

from geoface.texture.uv import MAP_CHANNELS as MAP_FILES  # noqa: E402  (argparse only: texture_uv imports no torch)


def _quiet(args):
    return True if getattr(args, "quiet", False) else None


def _read_photo(path) -> np.ndarray:
    """An RGB photo as float32 in [0, 1]; a grey or unreadable file is a one-line error."""
    from geoface.images import read_image

    img = read_image(path, "any")  # (a forged header claiming 60000^2 is refused before decoding)
    if img.ndim != 3 or img.shape[2] < 3:
        raise GeofaceError(f"{path} is not a readable RGB image")
    return np.ascontiguousarray(img[..., :3])


def _read_camera(path):
    from geoface.camera import Camera

    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
        if "Rt" in d:
            return Camera.from_matrix(d["K"], d["Rt"])
        return Camera.from_K(d["K"], d["R"], d["t"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise GeofaceError(f"{path}: a camera JSON needs K (3x3) and R (3x3) + t (3) or Rt (4x4) "
                           f"({type(e).__name__}: {e})") from None


def cmd_synth(args) -> int:
    from geoface._io import atomic_dir

    from geoface.texture.synth import make_texture_dataset
    with atomic_dir(args.output, overwrite=True) as tmp:  # complete or absent (the output policy ran first)
        paths = make_texture_dataset(tmp, args.count, args.res, args.map_res, seed=args.seed,
                                     vertices=args.vertices, quiet=_quiet(args), head_source=args.heads,
                                     supersample=args.supersample)
    print(f"{args.output}: {len(paths)} samples at {args.res}²")
    return 0


def _three(text: str, conv, msg: str) -> tuple:
    """Three comma-separated numbers >= 0, or a GeofaceError ``msg``."""
    try:
        out = tuple(conv(v) for v in text.split(","))
    except ValueError:
        out = ()
    if len(out) != 3 or min(out) < 0:
        raise GeofaceError(f"{msg}; got {text!r}")
    return out


def cmd_train(args) -> int:
    from geoface.texture.model import TextureTrainConfig, train_texture
    from geoface.texture.nets import TextureNetConfig
    epochs = _three(args.epochs, int, "--epochs must be three counts like 20,20,20 (predictor, GDE, HFDR)")
    weights = _three(args.map_weights, float, "--map-weights must be three weights like 1,4,1 (albedo, micronormal, specular)")
    hfdr_w = _three(args.hfdr_map_weights, float, "--hfdr-map-weights must be three weights like 1,8,1 (albedo, micronormal, specular)")
    tone = {k: v for k, v in (("gde_tone", args.gde_tone), ("hash_mode", args.hash_mode)) if v is not None}
    cfg = TextureTrainConfig(nets=TextureNetConfig(use_hash=not args.no_hash, hfdr_band=args.hfdr_band, **tone), gde_res=args.gde_res, k=args.k,
                             epochs=epochs, lr=args.lr, batch=args.batch, seed=args.seed, map_weights=weights,
                             hfdr_map_weights=hfdr_w)
    if args.init is not None:  # the networks' sizes come from the model trained before
        from geoface.texture.model import TextureModel
        nets = TextureModel.load(args.init).cfg.nets
        if nets.use_hash == args.no_hash:
            raise GeofaceError(f"{args.init} was trained {'with' if nets.use_hash else 'without'} hash encoding; "
                               "--no-hash must match it")
        if args.gde_tone not in (None, nets.gde_tone):
            raise GeofaceError(f"{args.init} reads {nets.gde_tone} tone; --gde-tone must match it")
        if args.hash_mode not in (None, nets.hash_mode):
            raise GeofaceError(f"{args.init} has hash mode {nets.hash_mode}; --hash-mode must match it")
        cfg.nets = dataclasses.replace(nets, hfdr_band=args.hfdr_band)  # sizes from it, the band as asked
    info = train_texture(args.data_dir, args.output, cfg, quiet=_quiet(args), init=args.init)
    last = {k: (f"{v[-1]:.4f}" if v else "-") for k, v in info["history"].items()}
    print(f"{args.output}: {info['samples']} samples of {info['size']}², {info['seconds']:.1f} s; final losses "
          + " ".join(f"{k} {v}" for k, v in last.items()))
    return 0


def cmd_reconstruct(args) -> int:
    from geoface.texture.model import TextureModel
    from geoface.texture.uv import CameraSeesNothingError, reconstruct_textures

    if (args.mesh is None) != (args.camera is None):
        raise GeofaceError("--mesh and --camera go together (the camera that took the photo of that mesh)")
    if args.track and (args.landmarks or args.mesh):
        raise GeofaceError("--track finds the landmarks in the photo; it replaces --landmarks and --mesh/--camera")
    if args.landmarks and args.mesh:
        raise GeofaceError("--landmarks fits the ICT head and its camera to the photo; it replaces --mesh and --camera")
    photo = _read_photo(args.photo)
    model = TextureModel.load(args.model)
    mesh = cam = L = None
    if args.track:
        L = "track"
    elif args.landmarks:
        from geoface.synth.ict_fit import load_landmarks

        L, size = load_landmarks(args.landmarks)
        H, W = photo.shape[:2]
        if size is not None and tuple(size) != (W, H):
            raise GeofaceError(f"{args.landmarks} was written for a {size[0]}x{size[1]} image; {args.photo} is {W}x{H}")
    elif args.mesh:
        from geoface.mesh.io import load_mesh

        mesh = load_mesh(args.mesh)
        if mesh.UV is None:
            raise GeofaceError(f"{args.mesh} has no UVs to project the maps into")
        cam = _read_camera(args.camera)
    try:
        rec = reconstruct_textures(model, photo, mesh=mesh, camera=cam, landmarks=L, focal=args.focal,
                                   uv_size=args.uv_size, k=args.k, refine=not args.no_refine)
    except CameraSeesNothingError as e:
        raise CameraSeesNothingError(f"{e} (check {args.camera or args.landmarks or 'the tracked face'})") from None
    images = {}
    for name in (*MAP_FILES, "uv", "normal"):
        img = rec.maps[name]
        images[name] = np.concatenate([img, np.zeros_like(img[:, :, :1])], 2) if img.shape[2] == 2 else img
    images.update({f"uv_{name}": img for name, img in rec.uv_maps.items()})
    msg = f"{args.output}: albedo, micronormal, specular ({photo.shape[0]}²)"
    if rec.uv_maps:
        msg += f"; UV maps {args.uv_size}² (seen by the camera: {rec.coverage:.0%} of texels)"
    if rec.fit is not None:
        msg += f"; ICT head fitted to the landmarks (RMS {rec.fit.rms_px:.2f} px, focal {rec.fit.focal:.0f} px)"
    out = Path(args.output)  # only now: a failure above leaves no partial output
    out.mkdir(parents=True, exist_ok=True)
    for name, img in images.items():
        save_image(out / f"{name}.png", img, bits=16)
    print(msg)
    return 0


def register(sub, common: argparse.ArgumentParser) -> None:
    """Add ``texture synth|train|reconstruct`` to the ``geoface`` sub-parsers."""
    s = sub.add_parser("texture", help="ultra-high-resolution skin maps from a photo (needs geoface[learn])")
    sd = s.add_subparsers(dest="what", metavar="WHAT")
    sd.required = True
    p = sd.add_parser("synth", parents=[common], help="write synthetic (photo, maps, UV, normal) samples")
    output_option(p, "OUT_DIR", "folder for the samples")
    p.add_argument("--count", type=number(int, 1, 100_000), default=8, help="photos to render (8)")
    p.add_argument("--res", type=number(int, 16, 8192), default=512, help="photo resolution")
    p.add_argument("--map-res", type=number(int, 16, 16384), default=None, help="UV-map resolution (default max(res, 1024))")
    p.add_argument("--vertices", type=number(int, 1000, 200_000), default=20000, help="procedural heads' vertex count")
    p.add_argument("--heads", choices=("procedural", "ict"), default="procedural",
                   help="ict: ICT-FaceKit people with random expressions and skin by facial region")
    p.add_argument("--supersample", type=number(int, 1, 4), default=2,
                   help="rendered pixels averaged per photo pixel, per side (1: point-sampled, aliased maps)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the heads, skins, lights and cameras (0)")
    p.set_defaults(func=cmd_synth)
    t = sd.add_parser("train", parents=[common], help="train predictor, GDE and HFDR in turn")
    t.add_argument("data_dir", metavar="DATA_DIR", help="a folder `texture synth` wrote (photos and their maps)")
    t.add_argument("-o", "--output", required=True, metavar="MODEL_DIR", help="folder for the trained model (new)")
    t.add_argument("--gde-res", type=number(int, 16, 4096), default=256, help="resolution of the predictor and GDE (paper: 1024)")
    t.add_argument("--k", type=number(int, 1, 64), default=4, help="HFDR patches per side")
    t.add_argument("--epochs", default="20,20,20", help="epochs of predictor, GDE, HFDR")
    t.add_argument("--lr", type=number(float, 0, 1, lo_open=True), default=1e-3, help="Adam learning rate (1e-3)")
    t.add_argument("--batch", type=number(int, 1, 4096), default=4, help="photos per step (4)")
    t.add_argument("--no-hash", action="store_true", help="GDE without the UV hash encoding (ablation)")
    t.add_argument("--hash-mode", choices=("input", "logit"), default=None,
                   help="where the hash features go: the GDE's input (the paper), or an offset of its output "
                        "logits per UV position (default: logit, as measured in docs/textures.md; with --init, its model's)")
    t.add_argument("--gde-tone", choices=("absolute", "relative"), default=None,
                   help="how the GDE reads skin tone: straight from the photo, or relative to the photo's tone "
                        "(default: absolute, as measured in docs/textures.md; with --init, its model's)")
    t.add_argument("--map-weights", default="1,1,1", metavar="A,M,S",
                   help="GDE loss weights of albedo, micronormal, specular (default equal, as the paper)")
    t.add_argument("--hfdr-map-weights", default="1,8,1", metavar="A,M,S",
                   help="HFDR loss weights of albedo, micronormal, specular (default 1,8,1, chosen on validation faces)")
    t.add_argument("--hfdr-band", choices=("full", "detail"), default="full",
                   help="what the HFDR refines: every band, or only the detail finer than the GDE's texels")
    t.add_argument("--init", default=None, metavar="MODEL_DIR",
                   help="start from this trained model's weights (e.g. --epochs 0,0,20 trains its HFDR further)")
    t.add_argument("--seed", type=SEED, default=0, help="seed of the initialisation and the batches (0)")
    t.set_defaults(func=cmd_train)
    r = sd.add_parser("reconstruct", parents=[common], help="albedo, micronormal, specular maps of a photo")
    r.add_argument("photo", metavar="PHOTO", help="a photo of a face (PNG or JPEG)")
    r.add_argument("--model", required=True, metavar="MODEL_DIR", help="a model `texture train` wrote")
    r.add_argument("--mesh", default=None, help="a mesh with UVs to project the maps into")
    r.add_argument("--camera", default=None, metavar="CAM.json", help="K, R, t of the photo's camera (OpenCV)")
    r.add_argument("--landmarks", default=None, metavar="L.json",
                   help="68 face landmarks of the photo (JSON, .npy, .txt, .pts): fit the ICT head and camera to them "
                        "and write the maps in its UV layout (instead of --mesh and --camera)")
    r.add_argument("--track", action="store_true",
                   help="find the 68 landmarks in the photo with MediaPipe (geoface[track]) and fit the ICT head to them: "
                        "the maps in its UV layout from the photo alone")
    r.add_argument("--focal", type=number(float, 1, 1e6), default=None, metavar="PX",
                   help="the photo's focal length in pixels, when known (e.g. from EXIF); else estimated")
    r.add_argument("--uv-size", type=number(int, 16, 16384), default=1024, help="side of the UV maps with --mesh/--landmarks/--track (1024)")
    r.add_argument("--k", type=number(int, 1, 64), default=None, help="patches per side (default: the model's)")
    r.add_argument("--no-refine", action="store_true", help="GDE maps upsampled (baseline), no HFDR")
    r.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="folder for the maps (new)")
    r.set_defaults(func=cmd_reconstruct)
