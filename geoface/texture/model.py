"""Training and streaming inference of the 4K-texture model (predictor → GDE → HFDR).

Data: a folder of ``*.npz`` samples, each with ``photo`` [H, W, 3], ``maps`` [H, W, 7]
(albedo, micronormal encoded, specular; see :mod:`geoface.texture.nets`), ``uv``
[H, W, 2], ``normal`` [H, W, 3] (encoded n/2 + ½) and ``mask`` [H, W] (face pixels), stored
as uint16 (values × 65535) so UVs keep 1/65535 precision at 4K.  H = W, divisible by ``k``.

Training (paper): the Normal&UV predictor first, at ``gde_res``; then the GDE with the UV hash
encoding jointly, on the predictor's (frozen) outputs; then, with both frozen, the HFDR on
random full-resolution patches with the upsampled GDE guidance.  Adam, ReduceLROnPlateau
(patience 5, on the loss of each epoch).  Losses are masked to face pixels.

Inference (:func:`reconstruct`): the photo is downsampled to ``gde_res`` for the predictor and
GDE; the HFDR then runs patch by patch over the full-resolution photo
(:func:`geoface.texture.patches.stream_patches`), each patch with its own guidance crops, and the
seams are smoothed.  Peak memory: the photo, the output maps and one patch of activations.
"""
from __future__ import annotations

import json
import os
import time
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as Fnn

from ..errors import CheckpointError, LearnError
from .patches import guidance_crop, smooth_seams_inplace, stream_patches
from .nets import GDE, HFDR, N_MAPS, NormalUVPredictor, TextureNetConfig, map_loss

KEYS = {"photo": 3, "maps": N_MAPS, "uv": 2, "normal": 3}


def save_sample(path, photo, maps, uv, normal, mask, landmarks=None) -> None:
    """Write one training sample (float arrays in [0, 1]) as uint16 npz, atomically;
    ``landmarks`` (optional): the face's 68 landmarks in pixels (x right, y down)."""
    arrs = {"photo": photo, "maps": maps, "uv": uv, "normal": normal}
    out = {k: np.round(np.clip(np.asarray(v, np.float64), 0, 1) * 65535).astype(np.uint16) for k, v in arrs.items()}
    out["mask"] = np.asarray(mask, bool)
    if landmarks is not None:
        out["landmarks"] = np.asarray(landmarks, np.float32).reshape(68, 2)
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez_compressed(tmp, **out)
    os.replace(tmp, path)


def load_sample(path, keys=None, box=None) -> dict:
    """→ dict of float32 arrays (photo, maps, uv, normal) and the bool mask; checks shapes.

    ``keys``: only these (default all, and the mask always); ``box``: a list of ``(rows, cols)``
    slice pairs — each array is then a list of its crops, converted after cropping (so a 4K
    sample costs its uint16 arrays, one at a time, not their float32 copies)."""
    keys = list(KEYS) if keys is None else list(keys)
    try:
        with np.load(path) as z:
            raw = {k: z[k] for k in [*keys, "mask"]}
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile) as e:
        raise LearnError(f"{path} is not a texture sample ({type(e).__name__}: {e})") from None
    H, W = raw["mask"].shape
    for k in keys:
        if raw[k].shape != (H, W, KEYS[k]):
            raise LearnError(f"{path}: {k} has shape {raw[k].shape}; expected {(H, W, KEYS[k])}")
    conv = lambda k, a: a.astype(bool) if k == "mask" else a.astype(np.float32) / 65535.0  # noqa: E731
    if box is None:
        return {k: conv(k, a) for k, a in raw.items()}
    return {k: [conv(k, a[ys, xs]) for ys, xs in box] for k, a in raw.items()}


def _t(a: np.ndarray) -> torch.Tensor:  # [H, W, C] -> [1, C, H, W]
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].float()


def _down(x: torch.Tensor, res: int) -> torch.Tensor:
    return x if x.shape[-1] == res else Fnn.interpolate(x, size=(res, res), mode="area")


@dataclass
class TextureTrainConfig:
    nets: TextureNetConfig = field(default_factory=TextureNetConfig)
    gde_res: int = 256  # the paper uses 1024; CPU-sized default
    k: int = 4  # patches per side at full resolution
    epochs: tuple = (20, 20, 20)  # predictor, GDE, HFDR
    lr: float = 1e-3
    batch: int = 4
    hfdr_patches: int = 4  # random patches per sample and step
    seed: int = 0
    #: loss weights of albedo, micronormal, specular in the GDE stage (the paper weighs them equally)
    map_weights: tuple = (1.0, 1.0, 1.0)
    #: the same for the HFDR stage: micronormal detail is a faint signal in the photo (a few
    #: percent of shading), and at equal weights the refiner barely learned it; chosen on the
    #: validation faces (docs/textures.md); None = ``map_weights``
    hfdr_map_weights: tuple | None = (1.0, 8.0, 1.0)

    def __post_init__(self):
        import math

        from geoface.nn.config import check_ranges

        def bad(name, want):
            raise CheckpointError(f"{name} must be {want}; got {getattr(self, name)!r}")

        check_ranges(self, ints={"gde_res": (8, 16384), "k": (1, 64), "batch": (1, 1 << 16), "hfdr_patches": (1, 1 << 16)},
                     reals={"lr": (0.0, 10.0, True, False)})
        if not (isinstance(self.epochs, (tuple, list)) and len(self.epochs) == 3
                and all(isinstance(e, int) and not isinstance(e, bool) and 0 <= e <= 1_000_000 for e in self.epochs)):
            bad("epochs", "three non-negative integers")
        for name in ("map_weights", "hfdr_map_weights"):
            w = getattr(self, name)
            if w is None and name == "hfdr_map_weights":
                continue
            if not (isinstance(w, (tuple, list)) and len(w) == 3
                    and all(isinstance(x, (int, float)) and math.isfinite(x) and x >= 0 for x in w)):
                bad(name, "three finite non-negative numbers")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["nets"] = self.nets.to_dict()
        d["epochs"] = list(self.epochs)
        d["map_weights"] = list(self.map_weights)
        if self.hfdr_map_weights is not None:
            d["hfdr_map_weights"] = list(self.hfdr_map_weights)
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "config.json") -> "TextureTrainConfig":
        from geoface.nn.config import config_from_dict

        def nets(v):
            if not isinstance(v, dict):
                raise CheckpointError(f"{where}: field 'nets' must be a JSON object; got {v!r}")
            return TextureNetConfig.from_dict(v, where=f"{where} (nets)")

        # a key the config does not have is a typo or another model's file: refused, naming it
        # ("version" is checked by the loader)
        body = {k: v for k, v in d.items() if k != "version"} if isinstance(d, dict) else d
        return config_from_dict(cls, body, where=where, unknown="error", convert_nested={"nets": nets})


class TextureModel(torch.nn.Module):
    def __init__(self, cfg: TextureTrainConfig):
        super().__init__()
        self.cfg = cfg
        self.predictor = NormalUVPredictor(cfg.nets.predictor_widths)
        self.gde = GDE(cfg.nets)
        self.hfdr = HFDR(cfg.nets)

    # ------------------------------------------------------------ inference pieces
    def coarse(self, photo_lo: torch.Tensor):  # [B,3,r,r] -> uv, normal (unit), GDE maps at r
        uv, n = self.predictor(photo_lo)
        return uv, n, self.gde(photo_lo, uv, n)

    def save(self, out_dir) -> None:
        from safetensors.torch import save_file
        out_dir = Path(out_dir)
        tmp = out_dir.with_name(f".{out_dir.name}.tmp")
        tmp.mkdir(parents=True, exist_ok=True)
        (tmp / "config.json").write_text(json.dumps(self.cfg.to_dict(), indent=2), encoding="utf-8")
        save_file({k: v.detach().cpu().contiguous() for k, v in self.state_dict().items()},
                  str(tmp / "model.safetensors"))
        from .._io import replace_dir, chmod_tree

        chmod_tree(tmp)  # the user's umask (safetensors writes 0600)
        replace_dir(tmp, out_dir)  # an old folder replaced whole; a link (with --force) replaced itself

    @classmethod
    def load(cls, model_dir) -> "TextureModel":
        from safetensors.torch import load_file
        model_dir = Path(model_dir)
        try:
            meta = json.loads((model_dir / "config.json").read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise CheckpointError(f"{model_dir}/config.json is missing or corrupt ({e})") from None
        if isinstance(meta, dict) and "version" in meta:
            from geoface.nn.config import check_version

            check_version(meta, 1, where=f"{model_dir}/config.json")
        cfg = TextureTrainConfig.from_dict(meta, where=f"{model_dir}/config.json")
        m = cls(cfg)
        try:
            m.load_state_dict(load_file(str(model_dir / "model.safetensors")), strict=True)
        except Exception as e:  # safetensors raises its own error types on truncation
            raise CheckpointError(f"{model_dir}/model.safetensors is missing, corrupt or does not match "
                                  f"config.json ({type(e).__name__})") from None
        return m.eval()


def _check_sizes(H: int, cfg: TextureTrainConfig) -> None:
    nets = cfg.nets
    m_gde = 2 ** (max(len(nets.gde_widths), len(nets.predictor_widths)) - 1)
    m_hfdr = 2 ** (len(nets.hfdr_widths) - 1)
    if H % cfg.k or (H // cfg.k) % m_hfdr:
        raise LearnError(f"image size {H} must split into k={cfg.k} patches per side whose size is "
                         f"divisible by {m_hfdr}")
    if cfg.gde_res > H or cfg.gde_res % m_gde:
        raise LearnError(f"gde_res={cfg.gde_res} must be <= the image size {H} and divisible by {m_gde}")


def _texels(size: int, H: int, gde_res: int) -> tuple[int, int]:
    """How many GDE texels a square patch of ``size`` full-resolution pixels spans."""
    n = max(int(round(size * gde_res / H)), 1)
    return n, n


def _masked_l1(a, b, m):
    return ((a - b).abs() * m).sum() / (m.sum() * a.shape[1]).clamp_min(1)


def _channel_weights(cfg: TextureTrainConfig, device, hfdr: bool = False) -> torch.Tensor:
    given = cfg.hfdr_map_weights if hfdr and cfg.hfdr_map_weights is not None else cfg.map_weights
    name = "hfdr_map_weights" if hfdr and cfg.hfdr_map_weights is not None else "map_weights"
    try:
        w = [float(x) for x in given]
    except (TypeError, ValueError):
        w = []
    if len(w) != 3 or min(w) < 0 or not np.isfinite(w).all() or max(w) == 0:
        raise LearnError(f"{name} must be three weights >= 0 (albedo, micronormal, specular); got {given}")
    return torch.tensor([w[0]] * 3 + [w[1]] * 3 + [w[2]], device=device)[None, :, None, None]


def train_texture(data_dir, out_dir, cfg: TextureTrainConfig | None = None, *, quiet: bool | None = None,
                  log=None, device: str = "cpu", init=None) -> dict:
    """Train the three stages on ``data_dir``/*.npz; writes ``out_dir`` (config + safetensors)
    and returns the per-stage loss history.  ``device``: "cpu" or "cuda".

    The data are streamed: memory holds the ``gde_res`` copies of the samples and, during the
    HFDR stage, one step's full-resolution patches (read from disk at each step), so a folder
    of 4K samples trains in the memory of one.

    ``init``: a trained model (folder) whose weights training starts from — with ``epochs``
    ``(0, 0, n)``, for example, only the HFDR is trained again; its networks must have the
    sizes ``cfg`` gives."""
    from geoface.progress import progress
    cfg = cfg or TextureTrainConfig()
    files = sorted(Path(data_dir).glob("*.npz"))
    if not files:
        raise LearnError(f"no *.npz texture samples in {data_dir}")
    torch.manual_seed(cfg.seed)
    g = torch.Generator().manual_seed(cfg.seed)
    model = TextureModel(cfg)
    if init is not None:
        src = TextureModel.load(init)
        try:
            model.load_state_dict(src.state_dict(), strict=True)
        except RuntimeError:
            raise LearnError(f"{init}: its networks differ from this configuration's (sizes or hash encoding)") from None
    model = model.to(device)
    wmap = _channel_weights(cfg, device)
    wmap_hfdr = _channel_weights(cfg, device, hfdr=True)
    # streamed: the samples are read one at a time; only their gde_res copies stay in memory,
    # and the HFDR stage reads its full-resolution patches from disk at each step
    lo: dict = {k: [] for k in KEYS}
    mlo = []
    H = None
    for f in progress(files, "texture data (low resolution)", quiet=quiet):
        d = load_sample(f)
        if H is None:
            H = d["mask"].shape[0]
            _check_sizes(H, cfg)
        if d["mask"].shape != (H, H):
            raise LearnError(f"{f}: the samples must all be {H}x{H}; this one is {d['mask'].shape}")
        for k in KEYS:
            lo[k].append(_down(_t(d[k]), cfg.gde_res))
        mlo.append(_down(torch.from_numpy(d["mask"])[None, None].float(), cfg.gde_res))
        del d
    lo = {k: torch.cat(v).to(device) for k, v in lo.items()}
    mlo = (torch.cat(mlo) > 0.5).float().to(device)
    n = len(files)
    hist: dict = {"predictor": [], "gde": [], "hfdr": []}
    t0 = time.time()

    def run_stage(name, params, step_fn, epochs):
        opt = torch.optim.Adam(params, lr=cfg.lr)
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=5)
        for _ in progress(range(epochs), f"texture {name}", quiet=quiet):
            perm = torch.randperm(n, generator=g).to(device)
            tot = 0.0
            for s in range(0, n, cfg.batch):
                idx = perm[s:s + cfg.batch]
                loss = step_fn(idx)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                tot += float(loss.detach()) * len(idx)
            sched.step(tot / n)
            hist[name].append(tot / n)
            if log:
                log(name, tot / n)

    def pred_step(idx):
        uv, nrm = model.predictor(lo["photo"][idx])
        m = mlo[idx]
        return _masked_l1(uv, lo["uv"][idx], m) + _masked_l1(nrm, lo["normal"][idx] * 2 - 1, m)

    run_stage("predictor", model.predictor.parameters(), pred_step, cfg.epochs[0])
    model.predictor.requires_grad_(False)
    with torch.no_grad():
        p_uv, p_n = (torch.cat(t) for t in zip(*(model.predictor(lo["photo"][s:s + cfg.batch]) for s in range(0, n, cfg.batch))))

    def gde_step(idx):
        out = model.gde(lo["photo"][idx], p_uv[idx], p_n[idx])
        m = mlo[idx]
        loss, _ = map_loss(out * m * wmap, lo["maps"][idx] * m * wmap, 1.0)  # eq.: L1 + 1·Laplacian
        return loss

    run_stage("gde", model.gde.parameters(), gde_step, cfg.epochs[1])
    model.gde.requires_grad_(False)
    with torch.no_grad():
        guide = torch.cat([model.gde(lo["photo"][s:s + cfg.batch], p_uv[s:s + cfg.batch], p_n[s:s + cfg.batch])
                           for s in range(0, n, cfg.batch)])
    P = H // cfg.k

    def hfdr_step(idx):
        xs, ts, ms, uvs, ns, gs = [], [], [], [], [], []
        for i in idx.tolist():
            boxes = []
            for _ in range(cfg.hfdr_patches):
                y0, x0 = (torch.randint(0, cfg.k, (2,), generator=g) * P).tolist()  # CPU generator
                boxes.append((slice(y0, y0 + P), slice(x0, x0 + P)))
            crops = load_sample(files[i], ("photo", "maps"), box=boxes)
            for j, box in enumerate(boxes):
                xs.append(_t(crops["photo"][j]))
                ts.append(_t(crops["maps"][j]))
                ms.append(torch.from_numpy(crops["mask"][j])[None, None].float())
                uvs.append(guidance_crop(p_uv[i:i + 1], (H, H), box))
                ns.append(guidance_crop(p_n[i:i + 1], (H, H), box))
                gs.append(guidance_crop(guide[i:i + 1], (H, H), box))
        cat = lambda a: torch.cat(a).to(device)  # noqa: E731
        out = model.hfdr(cat(xs), cat(uvs), cat(ns), cat(gs), grid=_texels(P, H, cfg.gde_res))
        m = cat(ms) * wmap_hfdr
        loss, _ = map_loss(out * m, cat(ts) * m, 2.0)  # L1 + 2·Laplacian
        return loss

    run_stage("hfdr", model.hfdr.parameters(), hfdr_step, cfg.epochs[2])
    model.requires_grad_(True)
    model.cpu().save(out_dir)
    return {"history": hist, "seconds": time.time() - t0, "samples": n, "size": H}


@torch.no_grad()
def reconstruct(model: TextureModel, photo: np.ndarray, *, k: int | None = None, refine: bool = True,
                smooth: bool = True, device: str = "cpu") -> dict:
    """Photo [H, W, 3] in [0, 1] (H = W, divisible by k) → dict of full-resolution maps
    ``albedo`` [H,W,3], ``micronormal`` [H,W,3] (encoded), ``specular`` [H,W,1], and the
    predicted ``uv`` [H,W,2] and ``normal`` [H,W,3] (encoded), all float32.

    ``refine=False`` gives the baseline: GDE maps bilinearly upsampled to H×W."""
    model.eval()
    photo = np.asarray(photo, np.float32)
    if photo.ndim != 3 or photo.shape[2] != 3 or photo.shape[0] != photo.shape[1]:
        raise LearnError(f"photo must be a square RGB image (H, H, 3); got shape {photo.shape}")
    if not np.isfinite(photo).all():
        raise LearnError("photo contains NaN or infinite values")
    k = k or model.cfg.k
    H = photo.shape[0]
    _check_sizes(H, TextureTrainConfig(**{**model.cfg.__dict__, "k": k}))
    model = model.to(device)
    x = _t(photo)  # stays on the CPU; patches move to ``device`` one at a time
    r = model.cfg.gde_res
    uv, nrm, guide = model.coarse(_down(x, r).to(device))
    if refine:
        def patch(i, j, ys, xs):
            box = (ys, xs)
            out = model.hfdr(x[:, :, ys, xs].to(device), guidance_crop(uv, (H, H), box),
                             guidance_crop(nrm, (H, H), box), guidance_crop(guide, (H, H), box),
                             grid=_texels(ys.stop - ys.start, H, r))
            return out[0].cpu().numpy()
        maps = stream_patches(patch, (H, H), k, N_MAPS)
        if smooth:
            smooth_seams_inplace(maps, k)
    else:
        maps = Fnn.interpolate(guide, size=(H, H), mode="bilinear", align_corners=False)[0].cpu().numpy()
    up = lambda t: Fnn.interpolate(t, size=(H, H), mode="bilinear", align_corners=False)[0].cpu().numpy()  # noqa: E731
    hwc = lambda a: np.ascontiguousarray(np.moveaxis(a, 0, -1)).astype(np.float32)  # noqa: E731
    return {"albedo": hwc(maps[0:3]), "micronormal": hwc(maps[3:6]), "specular": hwc(maps[6:7]),
            "uv": hwc(up(uv)), "normal": hwc(up(nrm) * 0.5 + 0.5)}
