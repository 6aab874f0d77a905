"""The HFM-GS model folder: saving and loading a registered avatar (weights, config, the
registration poses it was fitted in, the usage-pose calibration)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians
from geoface.hfm.model import HFMConfig, HFMModel
from geoface.avatar.model_dir import read_model_dir, write_model_dir


REGISTRATION_POSES = "registration_poses.npz"


def save_registration_poses(out_dir, R, t, pivot) -> None:
    """The registration poses a model was fitted in (``registration_poses.npz``: R [N, 3, 3],
    t [N, 3], pivot [3], as ``head_poses.npz``), for models whose poses training corrected."""
    from geoface._io import atomic_path

    with atomic_path(Path(out_dir) / REGISTRATION_POSES, suffix=".npz") as tmp:
        np.savez(tmp, R=np.asarray(R, np.float64), t=np.asarray(t, np.float64), pivot=np.asarray(pivot, np.float64))


def load_registration_poses(model_dir, n_frames: int | None = None):
    """(R, t, pivot) saved by :func:`save_registration_poses`, or None when the folder has none."""
    from geoface.errors import ModelFolderError

    path = Path(model_dir) / REGISTRATION_POSES
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            R, t, p = (np.asarray(z[k], np.float64) for k in ("R", "t", "pivot"))
        n = len(R) if n_frames is None else n_frames
        if R.shape != (n, 3, 3) or t.shape != (n, 3) or p.shape != (3,) or not all(np.isfinite(a).all() for a in (R, t, p)):
            raise ValueError(f"R {R.shape}, t {t.shape}, pivot {p.shape} for {n} frames")
    except (OSError, KeyError, ValueError) as e:
        raise ModelFolderError(f"{path}: not the registration poses of this model ({e})") from None
    return R, t, p


def save_hfm(model: HFMModel, out_dir) -> None:
    meta = {"format": HFMModel.FORMAT, "version": 1, "config": model.cfg.to_dict(),
            "y_split": model.y_split, "n_gaussians": len(model.gaussians)}
    if getattr(model, "landmarks3d", None):
        meta["landmarks3d"] = model.landmarks3d
    if getattr(model, "registration_size", None):  # the frames' size it learned from (a headset video's default)
        meta["registration_size"] = [int(v) for v in model.registration_size]
    if getattr(model, "pose_calibration", None):
        meta["pose_calibration"] = model.pose_calibration
    if getattr(model, "ict_identity", None):  # the registration capture's head (a headset video is tracked as it)
        meta["ict_identity"] = [float(x) for x in model.ict_identity]
    write_model_dir(out_dir, model, meta)


def load_hfm(model_dir) -> HFMModel:
    """Load a model folder; any problem is a one-line AvatarError."""
    d, meta, sd = read_model_dir(model_dir, HFMModel.FORMAT, "HFM-GS")
    conf = dict(meta["config"])
    conf.setdefault("map_norm", False)  # folders written before the field read p_L raw
    conf.setdefault("detach_lower", False)  # and trained the lower networks through the mapping
    conf.setdefault("upsample", "params")  # before the field: W_dist spread the keys' deformations
    conf.setdefault("feat_norm", False)  # and MLP_mapping read f_U as W_gm gave it
    conf.setdefault("mapping_heads", 1)
    conf.setdefault("image_pose", False)  # before the field: no pose read from the crop
    conf.setdefault("pose_residual", True)  # and MLP_pose always corrected the given pose
    conf.setdefault("pose_calibration", 0)  # and learned no calibration of the lower-landmark poses
    conf.setdefault("pose_calibration_expressions", 0)  # and drew no expressions for it
    if not conf.get("gaussian_mapping", True):  # before the field: the unmapped upper face had its own MLP
        conf.setdefault("unmapped_upper", "separate" if any(k.startswith("mlp_up.") for k in sd) else "shared")
    cfg = HFMConfig.from_dict(conf, where=f"{d}/config.json")
    from geoface.errors import ModelFolderError

    y_split = meta.get("y_split")
    size = meta.get("registration_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise ModelFolderError(f"{d}/config.json: registration_size must be [width, height]; got {size!r}")
    if isinstance(y_split, bool) or not isinstance(y_split, (int, float)) or not math.isfinite(y_split):
        raise ModelFolderError(f"{d}/config.json: y_split must be a number; got {y_split!r}")
    n_meta = meta.get("n_gaussians")
    if n_meta is not None and (isinstance(n_meta, bool) or not isinstance(n_meta, int)):
        raise ModelFolderError(f"{d}/config.json: n_gaussians must be an integer; got {n_meta!r}")
    try:
        n = sd["gaussians.means"].shape[0]
        g = Gaussians(sd["gaussians.means"], sd["gaussians.log_scales"], sd["gaussians.quats"],
                      sd["gaussians.opacity_logits"], sd["gaussians.colors"], sd.get("gaussians.parent"))
        model = HFMModel(g, cfg, meta["y_split"], sd["center"], sd["scale"])
        model.load_state_dict(sd, strict=True)
    except (KeyError, RuntimeError, AvatarError) as e:
        raise AvatarError(f"{d}: model weights do not match config.json ({str(e).splitlines()[0][:160]})") from None
    if n != meta.get("n_gaussians", n):
        raise AvatarError(f"{d}: {n} Gaussians in the weights, config.json says {meta['n_gaussians']}")
    lm = meta.get("landmarks3d")
    if lm is not None:
        try:
            names, pts = [str(n) for n in lm["names"]], np.asarray(lm["points"], np.float64)
            if pts.shape != (len(names), 3) or not np.isfinite(pts).all():
                raise ValueError(f"points {pts.shape} for {len(names)} names")
        except (KeyError, TypeError, ValueError) as e:
            raise ModelFolderError(f"{d}/config.json: landmarks3d needs names and [K, 3] points ({e})") from None
        model.landmarks3d = {"names": names, "points": pts.tolist()}
    model.pose_calibration = _read_calibration(meta.get("pose_calibration"), d)
    model.eval()
    model.refresh_keys()
    model.registration_size = tuple(size) if size is not None else None
    ident = meta.get("ict_identity")
    try:
        model.ict_identity = None if ident is None else identity_weights(ident)
    except ValueError as e:
        raise ModelFolderError(f"{d}/config.json: ict_identity must be up to 100 finite weights ({e})") from None
    return model


def identity_weights(value) -> list:
    """``value`` as ICT identity weights (1 to 100 finite numbers, a capture's ``ict_identity``);
    ValueError otherwise."""
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(str(e)) from None
    if a.ndim != 1 or not 0 < len(a) <= 100 or not np.isfinite(a).all():
        raise ValueError(f"shape {a.shape}" + ("" if np.isfinite(a).all() else ", not all finite"))
    return a.tolist()


def _read_calibration(cal, d):
    """config.json's ``pose_calibration`` checked for shape (None stays None)."""
    if cal is None:
        return None
    from geoface.errors import ModelFolderError

    try:
        fit, names = [str(n) for n in cal["fit_names"]], [str(n) for n in cal["names"]]
        a = {k: np.asarray(cal[k], np.float64) for k in ("pivot", "mean", "basis", "weights", "offset")}
        k = a["basis"].shape[0] if a["basis"].ndim == 2 else -1
        want = {"pivot": (3,), "mean": (3 * len(names),), "basis": (k, 3 * len(names)), "weights": (k, 6), "offset": (6,)}
        bad = [n for n, shp in want.items() if a[n].shape != shp or not np.isfinite(a[n]).all()]
        if "fit_weights" in cal:
            a["fit_weights"] = np.asarray(cal["fit_weights"], np.float64)
            if a["fit_weights"].shape != (len(fit),) or not (np.isfinite(a["fit_weights"]).all() and (a["fit_weights"] > 0).all()):
                bad.append("fit_weights")
        if "score_sd" in cal or "score_reach" in cal:  # models saved before the spreads were kept lack both
            a["score_sd"] = np.asarray(cal["score_sd"], np.float64)
            a["score_reach"] = np.asarray(float(cal["score_reach"]))
            if a["score_sd"].shape != (k,) or not (np.isfinite(a["score_sd"]).all() and (a["score_sd"] > 0).all()):
                bad.append("score_sd")
            if not (np.isfinite(a["score_reach"]) and a["score_reach"] > 0):
                bad.append("score_reach")
        if k < 1 or len(fit) < 4 or bad:
            raise ValueError(f"bad {bad or 'sizes'}")
    except (KeyError, TypeError, ValueError) as e:
        raise ModelFolderError(f"{d}/config.json: pose_calibration is malformed ({e})") from None
    return {"fit_names": fit, "names": names, **{n: v.tolist() for n, v in a.items()}}
